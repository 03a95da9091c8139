"""Pure code shared by every node package (no rclpy, no torch at import time)."""
