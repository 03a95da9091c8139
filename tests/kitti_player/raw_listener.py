"""A listener process for the replay tests: ``python raw_listener.py TOPIC COUNT`` subscribes
(reliable, depth 100) to std_msgs/String on TOPIC, prints ``ready`` once its subscription
exists, then ``heard: <data>`` per message, and exits 0 after COUNT messages (or on SIGINT /
SIGTERM)."""

import sys

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from rclpy.qos import QoSProfile, ReliabilityPolicy
from std_msgs.msg import String


def main(topic: str, count: int) -> None:
    node = Node("raw_listener")
    heard = []

    def on_msg(msg):
        heard.append(msg.data)
        print(f"heard: {msg.data}", flush=True)

    qos = QoSProfile(depth=100, reliability=ReliabilityPolicy.RELIABLE)
    node.create_subscription(String, topic, on_msg, qos)
    print("ready", flush=True)
    while rclpy.ok() and len(heard) < count:
        rclpy.spin_once(node, timeout_sec=0.1)


if __name__ == "__main__":
    rclpy.init(args=sys.argv)
    try:
        main(sys.argv[1], int(sys.argv[2]))
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        rclpy.try_shutdown()
