"""Subscribe to the tracked vehicles, the camera's odometry and its transform with nothing but
rclpy and the standard vision_msgs, nav_msgs and tf2_msgs interfaces (no project package).

    python examples/vehicle_subscriber.py            # beside a running graph
    python examples/vehicle_subscriber.py --ros-args -r __ns:=/rig2   # a namespaced graph

Prints one line per message:

    tracks <stamp> <frame> <id>:<x>,<y>,<z> ...        (vehicles/vision/tracks)
    odometry <stamp> <odom> <child> <x> <y> <z> <std>  (stereo/odometry)
    tf <stamp> <parent> <child> <x> <y> <z>            (tf)

Ctrl-C stops it (exit code 0).
"""

import math

import rclpy
from nav_msgs.msg import Odometry
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from tf2_msgs.msg import TFMessage
from vision_msgs.msg import Detection3DArray


def stamp(header) -> str:
    return f"{header.stamp.sec}.{header.stamp.nanosec:09d}"


class VehicleSubscriber(Node):
    def __init__(self):
        super().__init__("vehicle_subscriber")
        # relative names: the graph's namespace applies (remap __ns like the graph's nodes)
        self.create_subscription(Detection3DArray, "vehicles/vision/tracks", self.on_tracks, 10)
        self.create_subscription(Odometry, "stereo/odometry", self.on_odometry, 10)
        self.create_subscription(TFMessage, "tf", self.on_tf, 100)

    def on_tracks(self, msg: Detection3DArray) -> None:
        # one Detection3D per confirmed or coasting track: id = track id, class and score in
        # results[0].hypothesis, centre and its covariance in results[0].pose, size in bbox
        cars = []
        for d in msg.detections:
            p = d.results[0].pose.pose.position
            cars.append(f"{d.id}:{p.x:.2f},{p.y:.2f},{p.z:.2f}")
        print("tracks", stamp(msg.header), msg.header.frame_id, *cars, flush=True)

    def on_odometry(self, msg: Odometry) -> None:
        p = msg.pose.pose.position
        std = math.sqrt(max(msg.pose.covariance[0], 0.0))  # x variance, row-major 6x6
        print(
            "odometry",
            stamp(msg.header),
            msg.header.frame_id,
            msg.child_frame_id,
            f"{p.x:.3f} {p.y:.3f} {p.z:.3f} {std:.3f}",
            flush=True,
        )

    def on_tf(self, msg: TFMessage) -> None:
        for t in msg.transforms:
            v = t.transform.translation
            print(
                "tf",
                stamp(t.header),
                t.header.frame_id,
                t.child_frame_id,
                f"{v.x:.3f} {v.y:.3f} {v.z:.3f}",
                flush=True,
            )


def main():
    rclpy.init()
    node = VehicleSubscriber()
    try:
        rclpy.spin(node)
    except (KeyboardInterrupt, ExternalShutdownException):
        pass  # Ctrl-C or the context shut down: leave quietly
    finally:
        node.destroy_node()
        rclpy.try_shutdown()


if __name__ == "__main__":
    main()
