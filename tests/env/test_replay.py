"""The 3D replay (uvms_env.replay): what the recorder keeps, what the page's data says, the
page rebuilt from a trajectory.npz, and the page itself in a real headless browser.

The browser tests need a Chromium (Debian: ``apt-get install chromium-headless-shell``) and
skip without one; WebGL runs in software (SwiftShader). They open the page from disk, read
its console (no JavaScript error), a screenshot (the 3D view is drawn) and the DOM after
``#frame=K`` (the page writes its state, read from the placed meshes, into the DOM).
"""

from __future__ import annotations

import base64
import html
import json
import re
import shutil
import subprocess
from pathlib import Path

import numpy as np
import pytest

import uvms_env
from uvms_env.dynamics.spatial import rot_zyx
from uvms_env.dynamics.uvms import default_model
from uvms_env.replay import (
    ReplayRecorder,
    display,
    frame_indices,
    main,
    page_data,
    replay_from_trajectory,
    replay_path,
    window_max,
)
from uvms_env.task.constraints import CONSTRAINTS

BROWSERS = ("chromium-headless-shell", "chromium", "chromium-browser", "google-chrome")
BROWSER = next((p for p in map(shutil.which, BROWSERS) if p), None)
needs_browser = pytest.mark.skipif(
    BROWSER is None,
    reason="no headless Chromium on PATH (apt-get install chromium-headless-shell)",
)
CYCLES = 30
VIOLATED = range(10, 13)  # steps whose infos get a made-up joint_speed violation of robot 0


@pytest.fixture(scope="module")
def episode(tmp_path_factory: pytest.TempPathFactory) -> dict:
    """A short episode on holding inputs, recorded three ways: the recorder, the arrays of
    nmpc_expert's trajectory.npz and the step infos as the environment gave them."""
    env = uvms_env.parallel_env("short", max_cycles=CYCLES)
    env.reset(seed=0)
    recorder = ReplayRecorder(env)
    hold = env.sim.holding_inputs() / env.sim.tau_max
    arrays: dict[str, list] = {k: [] for k in ("t", "q", "zeta", "x_o", "v_o", "action")}
    live = []
    step = 0
    while env.agents:
        actions = {a: hold[i] for i, a in enumerate(env.agents)}
        _, _, _, _, infos = env.step(actions)
        st = env.sim.state
        for k, v in zip(arrays, (st.t, st.q, st.zeta, st.x_O, st.v_O, hold), strict=True):
            arrays[k].append(np.array(v, dtype=float))
        live.append([[infos[a][f"constraint_{c}"] for c in CONSTRAINTS] for a in infos])
        if step in VIOLATED:  # the page must show a violation where the infos report one
            infos = {a: dict(v) for a, v in infos.items()}
            infos["uvms_0"]["constraint_joint_speed"] = 0.25
        recorder.record(infos)
        step += 1
    out = tmp_path_factory.mktemp("replay")
    npz = out / "trajectory.npz"
    np.savez(npz, **{k: np.stack(v) for k, v in arrays.items()})
    (out / "metrics.json").write_text(json.dumps({"scenario": "short", "seed": 0}))
    page = recorder.write(out / "replay.html")
    return {
        "recorder": recorder,
        "ep": recorder.episode(),
        "arrays": {k: np.stack(v) for k, v in arrays.items()},
        "live": np.array(live),
        "npz": npz,
        "page": page,
    }


def decode(a: dict) -> np.ndarray:
    return np.frombuffer(base64.b64decode(a["b64"]), dtype=np.float32).reshape(a["shape"])


def rotate(quat: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate v by the unit quaternion (x, y, z, w)."""
    u, w = quat[:3], quat[3]
    return v + 2.0 * np.cross(u, np.cross(u, v) + w * v)


# -- the data ------------------------------------------------------------------------------
def test_frames_are_the_start_and_the_state_after_each_period(episode: dict) -> None:
    ep, arr = episode["ep"], episode["arrays"]
    assert len(ep.t) == CYCLES + 1 and ep.t[0] == 0.0
    np.testing.assert_array_equal(ep.q[1:], arr["q"])
    np.testing.assert_array_equal(ep.x_o[1:], arr["x_o"])
    np.testing.assert_allclose(ep.q[0], ep.scenario.initial_q)
    assert np.isnan(ep.g[0]).all()  # the start state is not evaluated by a step
    assert ep.metrics["episode_end"] == "max_cycles"


def test_page_places_the_model_and_the_object(episode: dict) -> None:
    ep = episode["ep"]
    data = page_data(ep)
    fr = {k: decode(v) for k, v in data["frames"].items()}
    model = default_model()
    for k in (0, 17, CYCLES):
        for i, q in enumerate(ep.q[k]):
            pts = np.array(model.body_points(q)).T
            np.testing.assert_allclose(fr["points"][k, i], display(pts), atol=1e-5)
            r = np.array(rot_zyx(q[3:6]))  # the body's x, y, z axes in NED
            for axis in range(3):
                got = rotate(fr["vehicle_quat"][k, i].astype(float), display(np.eye(3)[axis]))
                np.testing.assert_allclose(got, display(r[:, axis]), atol=1e-5)
        r_o = np.array(rot_zyx(ep.x_o[k, 3:]))
        for end in ep.segments.reshape(-1, 3):  # the object's segment ends in the world
            want = display(ep.x_o[k, :3] + r_o @ end)
            got = fr["object_pos"][k] + rotate(fr["object_quat"][k].astype(float), display(end))
            np.testing.assert_allclose(got, want, atol=1e-5)
    # display frame: depth (NED z, down) is minus "up"
    np.testing.assert_allclose(display([1.0, 2.0, 3.0]), [1.0, -3.0, 2.0])


def test_decimation_keeps_ends_and_violations() -> None:
    keep = frame_indices(1052, max_frames=100)
    assert keep[0] == 0 and keep[-1] == 1051 and len(keep) <= 100
    assert np.all(np.diff(keep) > 0)
    np.testing.assert_array_equal(
        frame_indices(1052, full_rate=True, max_frames=100), np.arange(1052)
    )
    g = np.full((1052, 2, 1), -1.0)
    g[0] = np.nan
    dropped = int(np.setdiff1d(np.arange(1052), keep)[5])
    g[dropped, 1, 0] = 0.3
    kept = window_max(g, keep)
    holder = int(np.searchsorted(keep, dropped))  # the first kept frame at or after it
    assert kept[holder, 1, 0] == 0.3 and kept[holder, 0, 0] == -1.0
    assert np.isnan(kept[0]).all() and (np.delete(kept[1:, 1, 0], holder - 1) == -1.0).all()


def test_replay_from_trajectory_recomputes_the_constraints(episode: dict, tmp_path: Path) -> None:
    ep = replay_from_trajectory(episode["npz"])
    np.testing.assert_allclose(ep.g[1:], episode["live"], atol=1e-9)
    np.testing.assert_array_equal(ep.q[1:], episode["arrays"]["q"])
    by_object = replay_from_trajectory(episode["npz"], episode["ep"].scenario, seed=0)
    np.testing.assert_array_equal(by_object.g, ep.g)
    out = main([str(episode["npz"]), "--out", str(tmp_path / "r.html")])
    text = out.read_text()
    assert "<script" in text and "http://" not in text.split("replay-data")[0]
    assert out.stat().st_size < 2e6


def test_replay_paths_are_file_names(tmp_path: Path) -> None:
    path = replay_path(tmp_path, "ppo:runs/a b+filter", "paper", 0)
    assert path == tmp_path / "replay_ppo_runs_a_b_filter_paper_0.html"


def test_page_is_self_contained(episode: dict) -> None:
    text = episode["page"].read_text()
    assert not re.search(r"<script[^>]+src=|<link[^>]+href=", text)  # nothing to fetch
    assert "three.js 0.187.0" in text and "OrbitControls" in text


# -- the page in a browser ------------------------------------------------------------------
def browse(page: Path, *args: str, fragment: str = "") -> subprocess.CompletedProcess:
    assert BROWSER is not None
    cmd = [
        BROWSER,
        "--headless",
        "--no-sandbox",  # CI runs as root
        "--use-angle=swiftshader",
        "--enable-unsafe-swiftshader",
        "--enable-logging=stderr",
        "--v=0",
        "--window-size=1000,700",
        "--virtual-time-budget=5000",
        *args,
        page.resolve().as_uri() + fragment,
    ]
    return subprocess.run(cmd, capture_output=True, text=True, timeout=120, check=False)


def console(proc: subprocess.CompletedProcess) -> list[str]:
    return [ln for ln in proc.stderr.splitlines() if ":CONSOLE" in ln]


def page_state(proc: subprocess.CompletedProcess) -> dict:
    m = re.search(r'<pre id="replay-state" hidden="">(.*?)</pre>', proc.stdout, re.S)
    assert m, proc.stdout[-2000:]
    return json.loads(html.unescape(m.group(1)))


@needs_browser
def test_page_runs_without_errors_and_draws(episode: dict, tmp_path: Path) -> None:
    from PIL import Image

    shot = tmp_path / "shot.png"
    proc = browse(episode["page"], f"--screenshot={shot}")
    lines = console(proc)
    # Chromium logs every console level alike: errors show as uncaught exceptions, error
    # objects, or three.js's own messages (a shader that fails to compile, a lost context)
    errors = [ln for ln in lines if re.search(r"Uncaught|Error|THREE\.", ln)]
    assert not errors, errors
    assert any("first frame rendered" in ln for ln in lines), proc.stderr[-3000:]
    image = np.asarray(Image.open(shot).convert("RGB"))
    view = image[: image.shape[0] - 80, : image.shape[1] - 320]  # the 3D view, no panel
    colors = np.unique(view.reshape(-1, 3), axis=0)
    assert len(colors) > 100, f"the 3D view has {len(colors)} colours: WebGL drew nothing?"


@needs_browser
def test_a_frame_places_the_vehicles_where_the_trajectory_says(episode: dict) -> None:
    ep = episode["ep"]
    for frame in (20, 12):
        state = page_state(browse(episode["page"], "--dump-dom", fragment=f"#frame={frame}"))
        assert state["frame"] == frame and state["period"] == frame
        assert state["t"] == pytest.approx(ep.t[frame], abs=1e-5)
        np.testing.assert_allclose(state["vehiclePositions"], ep.q[frame, :, :3], atol=1e-4)
        bad = frame - 1 in VIOLATED  # frame k shows the state after step k - 1 (0-based)
        assert state["violations"] == [["joint_speed"] if bad else [], []]
        assert state["markers"][0] == ("#d62728" if bad else "#2ca02c")
        assert state["markers"][1] == "#2ca02c"
