"""A bag folder left without a single message (a start that failed) does not block a rerun with
the same output; a bag that holds messages, or anything else in the folder, is never touched."""

from __future__ import annotations

import pytest
from vehicle_common.bags.writer import BagWriter, BagWriterError, empty_bag_files

TOPIC, TYPE = "/chatter", "std_msgs/msg/String"


def _string(text: str) -> bytes:
    from rclpy.serialization import serialize_message
    from std_msgs.msg import String

    return serialize_message(String(data=text))


def _snapshot(folder):
    return {p.name: p.read_bytes() for p in sorted(folder.iterdir())}


def test_an_empty_bag_is_replaced(tmp_path):
    bag = tmp_path / "run"
    closed = BagWriter(bag)  # closed with no message: metadata.yaml and an empty .mcap
    closed.add_topic(TOPIC, TYPE)
    closed.close()
    assert empty_bag_files(bag) is not None
    again = BagWriter(bag)
    assert again.replaced_empty
    again.add_topic(TOPIC, TYPE)
    again.write(TOPIC, _string("x"), 1)
    assert again.close() == {TOPIC: 1}


def test_a_bag_cut_before_its_first_message_is_replaced(tmp_path):
    bag = tmp_path / "run"
    killed = BagWriter(bag)  # never closed: the header only, as after kill -9 at start-up
    killed.add_topic(TOPIC, TYPE)
    killed._file.flush()
    assert not (bag / "metadata.yaml").exists()
    assert BagWriter(bag).replaced_empty
    (tmp_path / "empty").mkdir()
    assert BagWriter(tmp_path / "empty").replaced_empty


def test_recorded_data_is_never_replaced(tmp_path):
    bag = tmp_path / "run"
    writer = BagWriter(bag)
    writer.add_topic(TOPIC, TYPE)
    writer.write(TOPIC, _string("kept"), 1)
    writer.close()
    before = _snapshot(bag)
    with pytest.raises(BagWriterError, match="exists already and is not an empty bag"):
        BagWriter(bag)
    assert _snapshot(bag) == before
    # an empty bag beside a file that is not the recorder's: not touched either
    other = tmp_path / "other"
    empty = BagWriter(other)
    empty.close()
    (other / "notes.txt").write_text("mine")
    before = _snapshot(other)
    with pytest.raises(BagWriterError, match="exists already"):
        BagWriter(other)
    assert _snapshot(other) == before
    (tmp_path / "file").write_text("x")  # a file where the bag folder would go
    with pytest.raises(BagWriterError, match="exists already"):
        BagWriter(tmp_path / "file")
