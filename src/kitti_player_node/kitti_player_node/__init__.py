"""KITTI stereo player, synthetic KITTI-format sequence generator and MCAP bag replay."""
