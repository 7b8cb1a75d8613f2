"""The Python `mcap` package over a recording of mmnormd: the indexed (seeking) reader and the
stream reader must both read every message, agree on the count per channel, and find the
Foxglove schemas on their topics. Usage: mcap_read.py FILE.mcap"""
import sys
from collections import Counter

from mcap.reader import make_reader
from mcap.stream_reader import StreamReader
from mcap.records import Channel, Message, Schema

PATH = sys.argv[1]
EXPECTED = {
    "/tf": "foxglove.FrameTransform",
    "/robot/tcp_pose": "foxglove.PoseInFrame",
    "/scan/antennas": "foxglove.PointCloud",
    "/log": "foxglove.Log",
}


def main():
    with open(PATH, "rb") as f:
        reader = make_reader(f)
        summary = reader.get_summary()
        assert summary is not None, "no summary section: the indexed reader cannot seek"
        schemas = {s.id: s.name for s in summary.schemas.values()}
        topics = {c.topic: schemas.get(c.schema_id, "") for c in summary.channels.values()}
        indexed = Counter(ch.topic for _, ch, _ in reader.iter_messages())
        metadata = [m.name for m in reader.iter_metadata()]
    stream_channels = {}
    streamed = Counter()
    stream_schemas = {}
    with open(PATH, "rb") as f:
        for record in StreamReader(f, skip_magic=False).records:
            if isinstance(record, Schema):
                stream_schemas[record.id] = record.name
            elif isinstance(record, Channel):
                stream_channels[record.id] = record.topic
            elif isinstance(record, Message):
                streamed[stream_channels[record.channel_id]] += 1
    stats = summary.statistics
    print(f"indexed reader: {sum(indexed.values())} messages on {len(indexed)} topics "
          f"(statistics say {stats.message_count if stats else 'n/a'}); metadata {metadata}")
    print(f"stream reader: {sum(streamed.values())} messages")
    for topic in sorted(topics):
        print(f"  {topic}: {topics[topic]}, {indexed[topic]} messages")
    assert indexed == streamed, (indexed, streamed)
    assert stats is None or stats.message_count == sum(indexed.values())
    for topic, schema in EXPECTED.items():
        assert topics.get(topic) == schema, (topic, topics.get(topic))
        assert indexed[topic] > 0, topic
    assert "mmnormd" in metadata
    print("mcap: all checks passed")


if __name__ == "__main__":
    main()
