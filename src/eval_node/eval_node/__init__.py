"""MCAP bag recorder and offline evaluation of the pipeline by KITTI rules."""
