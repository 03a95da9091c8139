"""`evaluate bag` reads the formats bag_player replays: the same recorded run as rosbag2 MCAP,
rosbag2 sqlite3 and ROS 1 .bag (rewritten here with rosbags' writers) gives the same figures."""

from __future__ import annotations

import pytest

from tests.eval.test_evaluate_cli_bag import N_FRAMES, make_bag


def _rewrite(bag, tmp_path):
    """The bag's messages in a ROS 1 .bag and a sqlite3 rosbag2 (same timestamps)."""
    from rosbags.highlevel import AnyReader
    from rosbags.rosbag1 import Writer as Writer1
    from rosbags.rosbag2 import StoragePlugin
    from rosbags.rosbag2 import Writer as Writer2

    ros1, sqlite = tmp_path / "run.bag", tmp_path / "run_sqlite3"
    with AnyReader([bag]) as reader:
        ts = reader.typestore
        w2 = Writer2(sqlite, version=9, storage_plugin=StoragePlugin.SQLITE3)
        with Writer1(ros1) as w1, w2:
            conns: dict[str, tuple] = {}
            for conn, t, raw in reader.messages():
                if conn.topic not in conns:
                    conns[conn.topic] = tuple(
                        w.add_connection(conn.topic, conn.msgtype, typestore=ts) for w in (w1, w2)
                    )
                c1, c2 = conns[conn.topic]
                w1.write(
                    c1, t, ts.serialize_ros1(ts.deserialize_cdr(raw, conn.msgtype), conn.msgtype)
                )
                w2.write(c2, t, raw)
    return ros1, sqlite


def test_evaluate_bag_same_figures_for_ros1_sqlite3_and_mcap(tmp_path):
    from eval_node.bag_evaluation import evaluate_bag

    def figures(path):
        res = evaluate_bag(path, run_filters=False)
        return {k: v for k, v in res.items() if k not in ("bag", "throughput")}

    mcap = make_bag(tmp_path / "bag")
    ref = figures(mcap)
    assert ref["frames"] == N_FRAMES and ref["tracking"]["mota"] == pytest.approx(1.0)
    for other in _rewrite(mcap, tmp_path):
        assert figures(other) == ref, other
