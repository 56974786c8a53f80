"""The MCAP side of a recording: channels registered on first use, numeric payloads as JSON, events, camera
frames as foxglove.CompressedImage, small chunks flushed on request, and the summary at the end. It runs in
the writer process (hardware/recording/writer_process.py); nothing here is on the control loop's path.
"""

from __future__ import annotations

import os

from hardware.recording import schemas as S
from hardware.recording.protobuf_wire import encode_compressed_image


class McapSink:
    """Write one recording to the binary stream `f` (an open file). joint_names: {arm: [names]} for the
    channels' metadata; metadata: the recording metadata (str -> str), written first. OSError propagates:
    the caller decides what a full disk means."""

    def __init__(self, f, *, joint_names: dict[str, list[str]], metadata: dict[str, str],
                 clock_offset_s: float, compression: str = "zstd", chunk_size: int = 256 * 1024):
        from mcap.writer import CompressionType, Writer

        self._f = f
        self.joint_names = {k: list(v) for k, v in joint_names.items()}
        self.clock_offset_s = float(clock_offset_s)
        comp = {"zstd": CompressionType.ZSTD, "lz4": CompressionType.LZ4,
                "": CompressionType.NONE}[compression]
        self._w = Writer(f, chunk_size=chunk_size, compression=comp)
        self._channels: dict[str, int] = {}
        self._schemas: dict[str, int] = {}
        self.messages = self.frames = 0
        self._w.start(profile=S.PROFILE, library=f"factr2-recorder {metadata.get('software_version', '')}")
        self._w.add_metadata(S.RECORDING_METADATA, metadata)
        self._w.flush()

    def _channel(self, topic: str, schema_name: str, encoding: str, schema_enc: str, data, meta) -> int:
        """Channel id of topic, registered on first use (data and meta are callables: built once)."""
        cid = self._channels.get(topic)
        if cid is None:
            sid = self._schemas.get(schema_name)
            if sid is None:
                sid = self._schemas[schema_name] = self._w.register_schema(schema_name, schema_enc, data())
            cid = self._channels[topic] = self._w.register_channel(topic, encoding, sid, meta())
        return cid

    def numeric(self, schema: S.Schema, topic: str, payload: dict) -> None:
        arm = topic.split("/")[1]
        cid = self._channel(topic, schema.name, "json", "jsonschema", schema.schema_bytes,
                            lambda: {"arm": arm, "joint_names": ",".join(self.joint_names.get(arm, []))})
        ns = S.log_time_ns(payload["t"], self.clock_offset_s)
        self._w.add_message(cid, ns, S.encode_numeric(schema, payload), ns)
        self.messages += 1

    def event(self, t: float, kind: str, episode: int, text: str, value: float) -> None:
        cid = self._channel(S.TOPIC_EVENTS, S.EVENT_SCHEMA_NAME, "json", "jsonschema", S.event_json_schema,
                            dict)
        ns = S.log_time_ns(t, self.clock_offset_s)
        self._w.add_message(cid, ns, S.encode_event(t, kind, episode, text, value), ns)
        self.messages += 1

    def image(self, camera: str, t: float, jpeg: bytes) -> None:
        cid = self._channel(S.camera_topic(camera), S.IMAGE_SCHEMA_NAME, "protobuf", "protobuf",
                            lambda: S.image_schema()[2], lambda: {"camera": camera})
        ns = S.log_time_ns(t, self.clock_offset_s)
        self._w.add_message(cid, ns, encode_compressed_image(ns, jpeg, "jpeg", camera), ns)
        self.frames += 1
        self.messages += 1

    def flush(self, fsync: bool = False) -> None:
        """Close the chunk in progress and flush the file (fsync: also to the disk)."""
        self._w.flush()
        if fsync:
            os.fsync(self._f.fileno())

    def finish(self, stats: dict[str, str]) -> None:
        """The recorder's statistics, the summary and the footer; then the file is complete."""
        self._w.add_metadata(S.STATS_METADATA, stats)
        self._w.finish()
        self._f.flush()
        os.fsync(self._f.fileno())
