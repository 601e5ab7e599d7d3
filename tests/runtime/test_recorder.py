"""The MCAP recorder and echo, in-process and over loopback."""

from __future__ import annotations

import io
import json

import trio
import zenoh
from mcap.reader import make_reader

import qlap_runtime
from qlap_runtime.bus import keys
from qlap_runtime.bus.bridge import Publisher
from qlap_runtime.bus.recorder import echo, read_mcap, read_metadata, record
from qlap_runtime.bus.schema import Control, DeltaMsg, IACChoice, Motor, QState, Sense
from qlap_runtime.qlap.delta import Delta, SetK


def _publish(session, run_id: str, msgs: list[tuple[str, object]]) -> dict[str, Publisher]:
    """Put ``msgs`` on ``session``, one publisher per topic (returned, to be closed)."""
    pubs = {topic: Publisher(session, run_id, topic) for topic in {t for t, _ in msgs}}
    for topic, msg in msgs:
        pubs[topic].put(msg)
    return pubs


def _published(n: int) -> list[tuple[str, object]]:
    out: list[tuple[str, object]] = []
    for t in range(n):
        out.append(("sense", Sense(t, {"x": t / 10, "y": -t})))
        out.append(("qstate", QState(t, {"x": t % 3}, (("x", t % 3, 1),) if t % 2 else ())))
        out.append(("motor", Motor(t, {"u": 300.0})))
    out.append(("delta/dbn", DeltaMsg.of("dbn", Delta(1, 0, 0, (SetK(3),)))))
    out.append(("iac", IACChoice(n, "", 0.0, 0, True)))
    out.append(("control", Control("pause")))
    return out


async def test_recorder_in_process_writes_what_was_published(embedded, run_id, tmp_path):
    out = tmp_path / "run.mcap"
    msgs = _published(50)
    stop = trio.Event()
    summary_box: list = []
    async with trio.open_nursery() as nursery:
        await nursery.start(_record_task, embedded, run_id, out, stop, summary_box)
        pubs = _publish(embedded, run_id, msgs)
        embedded.put(keys.key(run_id, "sense"), b"garbage")  # counted, not recorded
        embedded.put(keys.key("other-run", "sense"), b'{"step":0,"values":{},"version":1}')
        await trio.sleep(0.2)
        # streamed to run.mcap.part; run.mcap appears whole, once the footer is written
        assert not out.exists() and (tmp_path / "run.mcap.part").is_file()
        stop.set()
    for p in pubs.values():
        p.close()
    assert not (tmp_path / "run.mcap.part").exists()
    summary = summary_box[0]
    assert summary.messages == len(msgs)
    assert summary.rejected == 1

    back = read_mcap(out)
    assert [(topic, msg) for topic, msg, _ in back] == [
        (keys.key(run_id, t), m) for t, m in msgs]
    times = [t for _, _, t in back]
    assert times == sorted(times) and times[0] > 1_600_000_000 * 10**9  # ns since the epoch

    summary_rec = _summary(out)
    schemas = {s.name: s for s in summary_rec.schemas.values()}
    assert schemas["qlap.Sense"].encoding == "jsonschema"
    assert json.loads(schemas["qlap.Sense"].data)["title"] == "Sense"
    # Stable topics: the run id is in the channel's metadata, not in the topic.
    channels = {c.topic: c for c in summary_rec.channels.values()}
    assert set(channels) == {f"/qlap/{t}" for t, _ in msgs}
    assert channels["/qlap/sense"].message_encoding == "json"
    assert channels["/qlap/sense"].metadata == {"run_id": run_id,
                                                "key": keys.key(run_id, "sense")}
    assert summary_rec.schemas[channels["/qlap/motor"].schema_id].name == "qlap.Motor"
    # One metadata record; the world is unknown (no status message): no scene either.
    [meta] = read_metadata(out)
    assert meta["run_id"] == run_id and "world" not in meta
    assert meta["software_version"] == qlap_runtime.__version__
    assert int(meta["start_time_ns"]) == times[0]
    assert summary.scenes == 0 and summary.runs == (run_id,)


async def test_record_and_echo_over_loopback(router_endpoint, run_id, tmp_path):
    out = tmp_path / "remote.mcap"
    printed = io.StringIO()
    stop = trio.Event()
    with zenoh.open(_client(router_endpoint)) as actor:
        async with trio.open_nursery() as nursery:
            await nursery.start(_record_task, [router_endpoint], run_id, out, stop, [])
            await nursery.start(_echo_task, router_endpoint, f"qlap/{run_id}/sense", stop,
                                printed)
            with Publisher(actor, run_id, "sense") as pub:
                with trio.fail_after(10):
                    await pub.wait_matched()
                    # two remote subscribers: wait until the router knows both
                    await trio.sleep(0.3)
                for t in range(100):
                    pub.put(Sense(t, {"x": float(t)}))
                await trio.sleep(0.5)
            stop.set()
    back = read_mcap(out)
    assert [m.step for _, m, _ in back] == list(range(100))
    lines = printed.getvalue().splitlines()
    assert len(lines) == 100
    assert lines[3] == (f'qlap/{run_id}/sense {{"step":3,"values":{{"x":3.0}},'
                        '"discontinuity":false,"version":1}')


def _summary(path):
    with open(path, "rb") as f:
        return make_reader(f).get_summary()


def _client(endpoint: str) -> zenoh.Config:
    from qlap_runtime.bus.config import client_config

    return client_config(endpoint)


async def _record_task(source, run_id, out, stop, box, *,
                       task_status=trio.TASK_STATUS_IGNORED):
    box.append(await record(source, run_id, out, stop, task_status=task_status))


async def _echo_task(endpoint, key, stop, printed, *, task_status=trio.TASK_STATUS_IGNORED):
    await echo(_client(endpoint), key, stop, out=printed, task_status=task_status)


def test_read_mcap_reads_files_written_before_the_topics_were_stable(tmp_path):
    from mcap.writer import Writer

    from qlap_runtime.bus.schema import encode, json_schema

    path = tmp_path / "old.mcap"
    with open(path, "wb") as f:     # the old layout: the key expression as the topic
        w = Writer(f)
        w.start()
        sid = w.register_schema(name="qlap.Sense", encoding="jsonschema",
                                data=json.dumps(json_schema(Sense)).encode())
        cid = w.register_channel(topic="qlap/old-run/sense", message_encoding="json",
                                 schema_id=sid)
        for t in range(3):
            w.add_message(channel_id=cid, log_time=t + 1, data=encode(Sense(t, {"x": 1.0})),
                          publish_time=t + 1)
        w.finish()
    assert read_mcap(path) == [("qlap/old-run/sense", Sense(t, {"x": 1.0}), t + 1)
                               for t in range(3)]
    assert read_metadata(path) == []


async def test_a_full_disk_ends_the_recording_not_the_caller(embedded, run_id, tmp_path):
    # run.mcap.part on a device that refuses every write (/dev/full: ENOSPC), as a full disk
    # does: the recorder returns with the reason, run.mcap is never written (not torn), and
    # its caller (the run) goes on.
    out = tmp_path / "run.mcap"
    (tmp_path / "run.mcap.part").symlink_to("/dev/full")
    msgs = _published(400)
    stop = trio.Event()
    summary_box: list = []
    async with trio.open_nursery() as nursery:
        await nursery.start(_record_task, embedded, run_id, out, stop, summary_box)
        pubs = _publish(embedded, run_id, msgs)
        await trio.sleep(0.2)
        stop.set()
    for p in pubs.values():
        p.close()
    [summary] = summary_box
    assert "No space left on device" in summary.error
    assert not out.exists()
