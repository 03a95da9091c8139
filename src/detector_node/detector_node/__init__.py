"""YOLOv2-style vehicle detector with 4-bin orientation (PyTorch), its training CLI and node."""
