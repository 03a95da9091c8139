"""3D multi-vehicle tracking (Kalman, particle, unfiltered) with data association."""
