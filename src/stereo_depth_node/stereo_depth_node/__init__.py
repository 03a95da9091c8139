"""SGBM + WLS disparity, point cloud and 3D ranging of 2D vehicle detections."""
