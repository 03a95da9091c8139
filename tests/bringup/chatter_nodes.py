"""Two tiny nodes for the launcher tests: ``talker`` publishes std_msgs/String on /chatter,
``listener`` exits with code 0 after hearing ``count`` messages; ``crasher`` exits with code 3."""

import sys

import rclpy
from rclpy.executors import ExternalShutdownException
from rclpy.node import Node
from std_msgs.msg import String


def talker() -> None:
    node = Node("talker")
    pub = node.create_publisher(String, "/chatter", 10)
    counter = [0]

    def tick():
        counter[0] += 1
        pub.publish(String(data=f"hello {counter[0]}"))

    node.create_timer(0.05, tick)
    rclpy.spin(node)


def listener() -> None:
    node = Node("listener")
    node.declare_parameter("count", 5)
    want = node.get_parameter("count").value
    heard = []

    def on_msg(msg):
        heard.append(msg.data)
        print(f"heard: {msg.data}", flush=True)

    node.create_subscription(String, "/chatter", on_msg, 10)
    while rclpy.ok() and len(heard) < want:
        rclpy.spin_once(node, timeout_sec=0.1)
    print(f"listener done after {len(heard)} messages", flush=True)


def crasher() -> None:
    node = Node("crasher")
    node.create_subscription(String, "/chatter", lambda m: sys.exit(3), 10)
    rclpy.spin(node)


if __name__ == "__main__":
    rclpy.init(args=sys.argv)
    try:
        {"talker": talker, "listener": listener, "crasher": crasher}[sys.argv[1]]()
    except (KeyboardInterrupt, ExternalShutdownException):
        pass
    finally:
        rclpy.try_shutdown()
