"""web (the viewer) without a browser: geometry, colours, run parsing, the recording, and the
live viewer's sessions driven through viser's own API."""

from __future__ import annotations

import json

import numpy as np
import pytest

from modsat_core.artefacts import ArtefactError, DesignReport, Trajectories
from web.viewer.recording import RECORDING_NAME, add_recording, recording_bytes, recording_html
from web.viewer.run import Episode, RunData
from web.viewer.scene import ACTUATOR_SRGB, Voxels, side_by_side_positions, srgb_to_linear

GRID = [[[1, 2, 0], [0, 1, 0], [0, 0, 0]], [[0, 0, 0], [0, 0, 0], [0, 0, 0]], [[0, 0, 0], [0, 0, 0], [0, 0, 0]]]


def _episode(T: int = 13, dt: float = 1 / 12) -> dict:
    t = np.arange(T) * dt
    angle = np.linspace(np.pi / 2, 0.0, T)  # about z, from 90 deg to the target
    q = np.stack([np.cos(angle / 2), 0 * t, 0 * t, np.sin(angle / 2)], axis=1)
    return {
        "t_s": t.tolist(),
        "q_BN": q.tolist(),
        "omega_B": np.tile([0, 0, -0.1], (T, 1)).tolist(),
        "h_B": np.tile([0, 0, 0.002], (T, 1)).tolist(),
        "tau_c_B": np.zeros((T, 3)).tolist(),
        "error_deg": np.degrees(angle).tolist(),
        "q_TN": [1.0, 0.0, 0.0, 0.0],
        "metrics": {"success": True, "slew_angle_deg": 90.0, "final_error_deg": 0.1},
    }


def _files() -> dict[str, bytes]:
    traj = Trajectories.model_validate({"policy": [_episode(), _episode(5)], "pd_baseline": [_episode(), _episode()]})
    spec = {"name": "unit", "algorithm": "td3-codesign"}
    return {
        "design.json": DesignReport.of(GRID).to_json(),
        "trajectories.json": traj.to_json(),
        "spec.json": json.dumps(spec).encode(),
    }


def test_srgb_to_linear_matches_the_standard_formula():
    assert np.allclose(srgb_to_linear((0, 255, 255)), [0.0, 1.0, 1.0])
    assert srgb_to_linear(0.5) == pytest.approx(0.21404, abs=1e-5)  # ((0.5 + 0.055) / 1.055) ** 2.4
    assert srgb_to_linear(0.02) == pytest.approx(0.02 / 12.92)
    orange = srgb_to_linear(ACTUATOR_SRGB)
    assert orange[0] == 1.0 and 0.2 < orange[1] < 0.22 and orange[2] < 0.005


def test_voxels_are_centred_on_the_centre_of_mass_and_coloured_by_type():
    vox = Voxels.from_grid(GRID)
    assert len(vox.positions) == 3 and np.allclose(vox.positions.mean(axis=0), 0.0)
    assert sorted(vox.types.tolist()) == [1, 1, 2]
    colors = vox.colors_linear
    assert np.allclose(colors[vox.types == 2], srgb_to_linear(ACTUATOR_SRGB))
    assert np.allclose(colors[vox.types == 1][:, 0], colors[vox.types == 1][:, 1])  # grey
    # Three cubes in an L share two faces: 3 * 12 edges - 2 * 4 shared = 28 distinct edges.
    seg = vox.edge_segments()
    assert seg.shape == (28, 2, 3)
    assert np.allclose(np.linalg.norm(seg[:, 1] - seg[:, 0], axis=1), 1.0)
    assert Voxels.from_grid(np.zeros((2, 2, 2))).edge_segments().shape == (0, 2, 3)


def test_side_by_side_placements_do_not_overlap():
    p = side_by_side_positions([2.0, 3.0])
    assert p[1][1] - p[0][1] >= 2.0 + 3.0
    assert side_by_side_positions([2.0]) == [(0.0, 0.0, 0.0)]


def test_the_viewer_opens_a_run_folder_without_its_optional_files(tmp_path):
    files = _files()
    for name in ("design.json", "trajectories.json"):  # an older run: no evaluation.json, no spec.json
        (tmp_path / name).write_bytes(files[name])
    run = RunData.from_dir(tmp_path)
    assert run.title == tmp_path.name and run.evaluation is None and run.spec is None
    assert len(run.episodes["policy"]) == 2 and run.modules == 3
    (tmp_path / "trajectories.json").unlink()
    with pytest.raises(ArtefactError, match=r"no trajectories\.json"):
        RunData.from_dir(tmp_path)


def test_run_data_reads_the_artefacts():
    files = _files()
    run = RunData.from_json(files["design.json"], files["trajectories.json"], spec=files["spec.json"])
    assert run.title == "unit" and run.short_algorithm == "RL" and run.modules == 3 and run.actuators == 1
    assert run.controllers == ["policy", "pd_baseline"]
    ep = run.episodes["policy"][0]
    assert isinstance(ep, Episode) and ep.q_BN.shape == (13, 4)
    assert ep.duration_s == pytest.approx(1.0)
    assert ep.index_at(0.0) == 0 and ep.index_at(0.5) == 6 and ep.index_at(99.0) == 12 and ep.index_at(-1) == 0
    assert ep.rate_rad_s[0] == pytest.approx(0.1) and ep.wheel_momentum_Nms[0] == pytest.approx(0.002)
    assert "90 deg slew, success" in ep.describe()


def test_run_data_refuses_files_not_in_their_format_and_names_them():
    files = _files()
    with pytest.raises(ArtefactError, match=r"design.json is not JSON"):
        RunData.from_json(b"not json", files["trajectories.json"])
    lopsided = json.dumps({"policy": [{**_episode(), "q_BN": [[1.0, 0.0, 0.0, 0.0]]}]})
    with pytest.raises(ArtefactError, match=r"trajectories.json .*policy\.0.*q_BN must be \(13, 4\)"):
        RunData.from_json(files["design.json"], lopsided)
    with pytest.raises(ArtefactError, match=r"design.json .*grid"):
        RunData.from_json(
            json.dumps({"grid": [[1, 2]], "grid_size": 1, "valid": True, "modules": 1, "actuators": 1}),
            files["trajectories.json"],
        )


def test_recording_is_a_viser_file_of_the_slews():
    files = _files()
    data = recording_bytes(files["design.json"], files["trajectories.json"], spec_json=files["spec.json"])
    assert 500 < len(data) < 200_000
    one = recording_bytes(files["design.json"], files["trajectories.json"], max_episodes=1)
    assert len(one) < len(data), "more slews, more frames"
    html = recording_html(data)
    assert html.startswith("<!doctype html>") and "__VISER_EMBED_DATA__" in html
    out = dict(files)
    assert add_recording(out) and out[RECORDING_NAME][:64] == data[:64]
    assert not add_recording({"spec.json": b"{}"}), "no design, no recording"
    broken = {"design.json": b"not json", "trajectories.json": b"{}"}
    assert not add_recording(broken) and RECORDING_NAME not in broken, "a failure never raises"


def test_a_1000_cell_design_is_drawn_and_recorded():
    """The biggest grid a spec allows (10x10x10), every cell filled, wheel units of three catalog types."""
    rng = np.random.default_rng(0)
    grid = rng.choice([1, 2, 3, 4], size=(10, 10, 10), p=[0.7, 0.1, 0.1, 0.1])
    vox = Voxels.from_grid(grid)
    assert len(vox.positions) == 1000 and np.allclose(vox.positions.mean(axis=0), 0.0)
    assert vox.colors_linear.shape == (1000, 3)
    assert np.allclose(vox.colors_linear[vox.types >= 2], srgb_to_linear(ACTUATOR_SRGB))  # every wheel type a unit
    assert vox.edge_segments().shape == (3 * 10 * 11 * 11, 2, 3)  # a full n^3 block: 3 n (n + 1)^2 edges
    files = _files()
    files["design.json"] = DesignReport.of(grid.tolist()).to_json()
    small = recording_bytes(_files()["design.json"], files["trajectories.json"])
    big = recording_bytes(files["design.json"], files["trajectories.json"])
    assert len(big) > len(small) and len(big) < 2_000_000


def test_live_viewer_sessions(tmp_path):
    """Sessions built as for a browser tab (viser's ClientHandle API), driven from Python."""
    from web.viewer.live import DirRuns, Session, ViewerApp

    for name in ("a", "b"):
        d = tmp_path / name
        d.mkdir()
        for k, v in _files().items():
            (d / k).write_bytes(v)
    app = ViewerApp(DirRuns([tmp_path / "a", tmp_path / "b"]), port=0)
    try:
        assert app.port > 0
        # The server-wide scene/gui API stands in for one client's (same methods).
        fake = type(
            "Client",
            (),
            {
                "scene": app.server.scene,
                "gui": app.server.gui,
                "client_id": 0,
                "atomic": app.server.atomic,
                "camera": type("Cam", (), {})(),
            },
        )()
        s = Session(app, fake, {"run": "1", "compare": "2", "controller": "pd_baseline", "t": "0.5"})
        assert [r.title for r in s.runs] == ["a", "b"] and len(s.sats) == 2
        assert s.ctrl_dd.value == "PD baseline" and s.ep_dd.options[0].startswith("1: 90 deg slew")
        assert s.t == pytest.approx(0.5) and "t = 0.50 s" in s.readout.content
        q = s.sats[0].body.wxyz
        assert np.allclose(q, _episode()["q_BN"][6]), "the body frame shows q_BN at t"
        s._toggle_play()
        s.tick(10.0)  # past the end: stops there
        assert not s.playing and s.t == pytest.approx(1.0)
        s.cmp_dd.value = "(none)"
        assert len(s.runs) == 1
    finally:
        app.stop()


def _handshake(port: int, headers: list[tuple[str, str]], *, upgrade: bool = True) -> str:
    """The status line the viewer answers to a raw HTTP request (a websocket upgrade or a GET)."""
    import socket

    lines = ["GET /?run=1 HTTP/1.1", *(f"{k}: {v}" for k, v in headers)]
    if upgrade:
        lines += [
            "Upgrade: websocket",
            "Connection: Upgrade",
            "Sec-WebSocket-Key: dGhlIHNhbXBsZSBub25jZQ==",
            "Sec-WebSocket-Version: 13",
            "Sec-WebSocket-Protocol: viser-v1.1.1",
        ]
    with socket.create_connection(("127.0.0.1", port), timeout=10) as sock:
        sock.sendall(("\r\n".join(lines) + "\r\n\r\n").encode())
        data = b""
        while b"\r\n" not in data:
            chunk = sock.recv(4096)
            if not chunk:
                break
            data += chunk
    return data.split(b"\r\n", 1)[0].decode()


def test_live_viewer_refuses_other_sites_at_the_handshake(tmp_path, caplog):
    """A websocket from a page of another site, or naming a host this viewer does not answer to
    (DNS rebinding), is refused before the 101 (no session, no scene message); the page itself is
    not served to a foreign host either; a repeated Host header is a plain 400, not a traceback.
    The service's own page, on another port of localhost, is served (tests/web drive that one in a
    real browser)."""
    import logging

    from web.viewer.live import DirRuns, ViewerApp
    from web.viewer.origin import host_names, origin_allowed

    d = tmp_path / "a"
    d.mkdir()
    for k, v in _files().items():
        (d / k).write_bytes(v)
    app = ViewerApp(DirRuns([d]), port=0)
    try:
        here = f"127.0.0.1:{app.port}"
        with caplog.at_level(logging.INFO):
            assert " 101 " in _handshake(app.port, [("Host", here), ("Origin", "http://127.0.0.1:8000")]), "the page"
            assert " 101 " in _handshake(app.port, [("Host", here), ("Origin", "http://localhost:8000")])
            assert " 101 " in _handshake(app.port, [("Host", here)]), "no Origin: not a browser"
            assert " 200 " in _handshake(app.port, [("Host", here)], upgrade=False), "viser's client"
            assert " 403 " in _handshake(app.port, [("Host", here), ("Origin", "http://evil.example")])
            assert " 403 " in _handshake(app.port, [("Host", here), ("Origin", "null")])
            evil = [("Host", "evil.example:8080"), ("Origin", "http://evil.example:8080")]
            assert " 400 " in _handshake(app.port, evil), "DNS rebinding: a foreign Host"
            assert " 400 " in _handshake(app.port, [("Host", "evil.example")], upgrade=False), "the page too"
            assert " 400 " in _handshake(app.port, [("Host", here), ("Host", here)])
            assert " 400 " in _handshake(app.port, [("Host", here), ("Origin", "http://a"), ("Origin", "http://b")])
        assert "refused a websocket: a page of another site ('http://evil.example')" in caplog.text
        assert not [r for r in caplog.records if r.exc_info or r.levelno >= logging.ERROR], caplog.text
    finally:
        app.stop()
    assert host_names("0.0.0.0", "sat.lab, 10.0.0.5") == {"localhost", "127.0.0.1", "::1", "sat.lab", "10.0.0.5"}
    assert host_names("127.0.0.1", "*") is None and origin_allowed("http://evil.example", None)
    assert not origin_allowed("http://[bad", {"localhost"})
