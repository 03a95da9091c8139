"""Bag I/O of the project, one module family (pure core: no rclpy at import time).

- :mod:`.reader`: open any bag (rosbag2 MCAP or sqlite3, bare ``.mcap``, ROS 1 ``.bag``), read
  an interrupted one up to its last complete chunk, one line for a damaged one (``BagError``).
- :mod:`.writer`: write rosbag2/MCAP bags from serialized messages (``BagWriter``, the core of
  the ``bag_recorder`` node in ``eval_node.recorder``).
- :mod:`.metadata`: rosbag2's ``metadata.yaml`` and per-file compression, for the writer and
  the recovery.
- :mod:`.mcap_scan`, :mod:`.mcap_repair`: one MCAP file walked record by record (cut or
  damaged) and written again with a summary and footer.
- :mod:`.recovery`: a whole bag after a crash (the ``bag_recover`` console script).
- :mod:`.replay`: messages as (topic, type, time, CDR bytes) with topic selection, remapping,
  stamp sync and pacing (the core of the ``bag_player`` node in ``kitti_player_node``).
- :mod:`.recorded_run`: a recorded run of the graph read back into per-frame KITTI objects
  (what ``evaluate bag``, the demo and the benches score).
- :mod:`.repeated_stamps`: a stamp seen twice on a per-frame topic, the sign of two runs mixed
  in one recording (the recorder warns, :mod:`.recorded_run` refuses).
"""
