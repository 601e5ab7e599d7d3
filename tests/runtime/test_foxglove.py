"""Recordings for Foxglove: stable topics, the run's metadata record, and the world's bodies as
``foxglove.SceneUpdate``, read back with the mcap reader from real runs."""

from __future__ import annotations

import json
from datetime import datetime

import numpy as np
import trio
import zenoh
from foxglove_schemas_protobuf.SceneUpdate_pb2 import SceneUpdate
from google.protobuf import descriptor_pool, message_factory
from google.protobuf.descriptor_pb2 import FileDescriptorSet
from mcap.reader import make_reader

import worlds
from qlap_runtime.agent_run import params_for_world
from qlap_runtime.bus import keys
from qlap_runtime.bus.auth import CREDENTIALS_FILE, read_credentials
from qlap_runtime.bus.bridge import Publisher
from qlap_runtime.bus.config import BusConfigError, client_config
from qlap_runtime.bus.foxglove import file_descriptor_set
from qlap_runtime.bus.recorder import read_mcap, read_metadata, record
from qlap_runtime.bus.schema import AgentStatus, Sense
from qlap_runtime.placements.launcher import run_embedded, run_embedded_async
from qlap_runtime.qlap import Params
from qlap_runtime.runtime.context import RunContext

from .conftest import free_port

ENTITY_FIELDS = {"timestamp", "frame_id", "id", "metadata", "cubes", "spheres"}


def _context(tmp_path, world: str, steps: int, seed: int, run_id: str) -> RunContext:
    w = worlds.make(world)
    params = params_for_world(w, Params(babble_steps=steps))
    w.close()
    return RunContext(run_id, world, steps, seed, params, out=tmp_path / run_id)


def _read(path):
    """(summary, [(schema, channel, message)]) of an MCAP file, in log-time order."""
    with open(path, "rb") as f:
        reader = make_reader(f)
        return reader.get_summary(), list(reader.iter_messages(log_time_order=True))


def _scene_class(summary):
    """The SceneUpdate class built from the file's own schema (not from the package), so that
    parsing with it checks the messages against the schema the file carries."""
    [schema] = [s for s in summary.schemas.values() if s.name == "foxglove.SceneUpdate"]
    assert schema.encoding == "protobuf"
    fds = FileDescriptorSet.FromString(schema.data)
    pool = descriptor_pool.DescriptorPool()
    for fd in fds.file:
        pool.Add(fd)
    # Foxglove's official schema, as the foxglove-schemas-protobuf package ships it.
    assert schema.data == file_descriptor_set(SceneUpdate)
    assert fds.file[-1].name == "foxglove/SceneUpdate.proto"
    return message_factory.GetMessageClass(pool.FindMessageTypeByName("foxglove.SceneUpdate"))


def _scenes(path) -> list[tuple[int, int, dict]]:
    """Every scene update as (log time, step, {entity id: (shape, position, size, rgba)}),
    parsed with the file's schema."""
    summary, messages = _read(path)
    cls = _scene_class(summary)
    out = []
    for _schema, channel, message in messages:
        if channel.topic != "/qlap/scene":
            continue
        assert channel.message_encoding == "protobuf"
        update = cls.FromString(message.data)
        assert update.SerializeToString() == message.data
        bodies, steps = {}, set()
        for e in update.entities:
            assert {f.name for f, _ in e.ListFields()} <= ENTITY_FIELDS
            assert e.frame_id == "world"
            assert e.timestamp.ToNanoseconds() == message.log_time
            steps.add(dict((kv.key, kv.value) for kv in e.metadata)["step"])
            [prim] = [*e.cubes, *e.spheres]
            shape = "box" if e.cubes else "sphere"
            p, s, c, q = prim.pose.position, prim.size, prim.color, prim.pose.orientation
            assert (q.x, q.y, q.z, q.w) == (0, 0, 0, 1)
            bodies[e.id] = (shape, (p.x, p.y, p.z), (s.x, s.y, s.z), (c.r, c.g, c.b, c.a))
        [step] = steps
        out.append((message.log_time, int(step), bodies))
    return out


def test_embedded_core2d_run_recording(tmp_path):
    """``qlap run --headless --world core2d --steps 2000 --record F.mcap``, through its Python
    API: stable topics, one metadata record with the run's context, and the scene."""
    ctx = _context(tmp_path, "core2d", 2000, 7, "fox-2d")
    out = tmp_path / "run.mcap"
    run_embedded(ctx, record=out)

    summary, messages = _read(out)
    topics = {c.topic for c in summary.channels.values()}
    assert topics >= {"/qlap/sense", "/qlap/qstate", "/qlap/motor", "/qlap/status",
                      "/qlap/world", "/qlap/scene"}
    assert topics <= {f"/qlap/{t}" for t in keys.TOPICS} | {"/qlap/scene"}
    assert all(c.metadata["run_id"] == "fox-2d" for c in summary.channels.values())

    [meta] = read_metadata(out)
    assert meta["run_id"] == "fox-2d"
    assert meta["world"] == "core2d" and meta["seed"] == "7" and meta["steps"] == "2000"
    assert meta["placement"] == "embedded"
    assert json.loads(meta["params"]) == json.loads(json.dumps(ctx.params.to_dict()))
    assert meta["software_version"]
    first = min(m.log_time for _, _, m in messages)
    assert int(meta["start_time_ns"]) == first
    start = datetime.fromisoformat(meta["start_time"][:26] + "+00:00")   # to the microsecond
    assert abs(start.timestamp() - first / 1e9) < 1e-5

    senses = {m.step: m.values for k, m, _ in read_mcap(out) if k.endswith("/sense")}
    assert sorted(senses) == list(range(2000))
    for topic in ("qstate", "motor"):       # the hosted chain's hops, beside it on the bus
        steps = [m.step for k, m, _ in read_mcap(out) if k.endswith(f"/{topic}")]
        assert sorted(steps) == list(range(2000)), topic
    scenes = _scenes(out)
    assert 5 <= len(scenes) < 2000
    gaps = np.diff([t for t, _, _ in scenes])
    assert gaps.min() >= 1e9 / 30 - 1                       # at most 30 a second (default)
    for _, step, bodies in scenes:
        v = senses[step]
        assert set(bodies) == {"table", "hand", "block"}
        shape, pos, size, _ = bodies["hand"]
        assert shape == "box" and size == (3.0, 3.0, 0.5)
        assert pos == (-v["h_x"], v["h_y"], 11.0)           # x mirrored: a right-handed frame
        width = v["x_LR"] - v["x_RL"] - 3.0
        _, pos, size, _ = bodies["block"]
        np.testing.assert_allclose(size, (width,) * 3, atol=1e-9)
        np.testing.assert_allclose(pos, (-(v["T_L"] + 4), v["T_T"] + 4, v["z_F"] + width / 2),
                                   atol=1e-9)
        assert bodies["table"][1:3] == ((6.5, -1.0, 9.5), (21.0, 10.0, 2.0))


async def test_connected_recorder_learns_the_run_from_its_status(tmp_path):
    """``qlap record --connect`` to a core run started with ``--listen``: no run context, so
    world, seed and placement come from the run's status messages; the 3D hand is at h_z."""
    ctx = _context(tmp_path, "core", 1500, 3, "fox-core")
    endpoint = f"tcp/127.0.0.1:{free_port()}"
    out = tmp_path / "connected.mcap"
    stop = trio.Event()
    box: list = []

    config: list = []

    async def recorder(task_status=trio.TASK_STATUS_IGNORED):
        box.append(await record(config[0], None, out, stop, task_status=task_status))

    async with trio.open_nursery() as nursery:
        done = trio.Event()

        async def run():
            await run_embedded_async(ctx, (endpoint,))
            done.set()
        nursery.start_soon(run)
        with trio.fail_after(60):
            cred = ctx.out / CREDENTIALS_FILE   # the run listens with authentication
            while True:                  # until the run's session listens
                try:
                    _, password, _ = read_credentials(cred, "viewer")
                    config[:] = [client_config([endpoint], user="viewer", password=password)]
                    with zenoh.open(client_config([endpoint], user="viewer",
                                                  password=password)):
                        break
                except (zenoh.ZError, BusConfigError):
                    await trio.sleep(0.1)
            await nursery.start(recorder)
            await done.wait()
        await trio.sleep(0.3)
        stop.set()

    summary = box[0]
    assert summary.runs == ("fox-core",) and summary.scenes > 0
    [meta] = read_metadata(out)
    assert (meta["run_id"], meta["world"], meta["seed"]) == ("fox-core", "core", "3")
    assert meta["placement"] == "embedded" and "params" not in meta
    senses = {m.step: m.values for k, m, _ in read_mcap(out) if k.endswith("/sense")}
    scenes = _scenes(out)
    assert len(scenes) == summary.scenes
    for _, step, bodies in scenes:
        v = senses[step]
        assert set(bodies) == {"table", "hand", "block"} | {f"table_leg{i}" for i in range(1, 5)}
        assert bodies["hand"][1:3] == ((-v["h_x"], v["h_y"], v["h_z"]), (3.0, 3.0, 0.5))
        width = bodies["block"][2][0]
        assert abs(width - (v["x_LR"] - v["x_RL"] - 3.0)) < 1e-9 and 1.0 <= width <= 3.0
        _, pos, _, _ = bodies["block"]
        np.testing.assert_allclose(pos[:2], (v["c_x"] - v["h_x"], v["h_y"] - v["c_y"]),
                                   atol=1e-9)
        # its height, drawn from h_z and z_BT, agrees with z_F (its bottom above the floor)
        assert abs(pos[2] - width / 2 - v["z_F"]) < 1e-9


async def test_two_runs_one_file_and_a_scene_per_sense(embedded, tmp_path):
    """Recording every run: both keep the same topics (their run ids in the channels'
    metadata), each has its own metadata record, and ``scene_hz=0`` draws every sense."""
    out = tmp_path / "two.mcap"
    stop = trio.Event()
    box: list = []
    world = worlds.make("core2d")
    rng = np.random.default_rng(0)

    async def recorder(task_status=trio.TASK_STATUS_IGNORED):
        box.append(await record(embedded, None, out, stop, scene_hz=0, task_status=task_status))

    async with trio.open_nursery() as nursery:
        await nursery.start(recorder)
        for i, run in enumerate(("run-a", "run-b")):
            with Publisher(embedded, run, "status") as st, \
                    Publisher(embedded, run, "sense") as pub:
                st.put(AgentStatus(0, 0.0, "babble", world="core2d", seed=10 + i,
                                   placement="local"))
                obs = world.reset(seed=i)
                for t in range(20):
                    pub.put(Sense(t, obs))
                    obs = world.step({"u_x": float(rng.uniform(-1e3, 1e3)),
                                      "u_y": float(rng.uniform(-1e3, 1e3))})
                    await trio.sleep(0.002)             # distinct receive times
        await trio.sleep(0.3)
        stop.set()
    world.close()

    assert box[0].scenes == 40 and box[0].runs == ("run-a", "run-b")
    metas = sorted(read_metadata(out), key=lambda m: m["run_id"])
    assert [(m["run_id"], m["world"], m["seed"], m["placement"]) for m in metas] == [
        ("run-a", "core2d", "10", "local"), ("run-b", "core2d", "11", "local")]
    summary, _ = _read(out)
    by_topic: dict[str, set] = {}
    for c in summary.channels.values():
        by_topic.setdefault(c.topic, set()).add(c.metadata["run_id"])
    assert by_topic == {t: {"run-a", "run-b"} for t in ("/qlap/status", "/qlap/sense",
                                                         "/qlap/scene")}
    keys_back = [k for k, _, _ in read_mcap(out)]
    assert keys_back.count("qlap/run-a/sense") == keys_back.count("qlap/run-b/sense") == 20
    assert len(_scenes(out)) == 40
