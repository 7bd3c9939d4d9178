"""web (the viewer) without a browser: geometry, colours, run parsing, the recording, and the
live viewer's sessions driven through viser's own API."""

from __future__ import annotations

import json

import numpy as np
import pytest

from modsat_core.artefacts import ArtefactError, DesignReport, Trajectories
from web.viewer.recording import RECORDING_NAME, add_recording, recording_bytes, recording_html
from web.viewer.run import Episode, RunData, payload_cells
from web.viewer.scene import (
    ACTUATOR_SRGB,
    PAYLOAD_OPACITY,
    PAYLOAD_SRGB,
    STRUCTURE_OPACITY,
    STRUCTURE_SRGB,
    Voxels,
    draw_satellite,
    side_by_side_positions,
    srgb_to_linear,
)

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


#: A 3x3x3 design with a payload plate on k = 0 and one wheel unit at the centre.
PLATE_GRID = np.ones((3, 3, 3), dtype=int)
PLATE_GRID[1, 1, 1] = 2
PLATE = [[i, j, 0] for i in range(3) for j in range(3)]


class _Scene:
    """Records what draw_satellite asks of a viser scene."""

    def __init__(self):
        self.meshes: dict[str, dict] = {}
        self.removed: list[str] = []

    def add_frame(self, name, **kw):
        return type("Frame", (), {"wxyz": kw.get("wxyz")})()

    def add_batched_meshes_simple(self, name, vertices, faces, wxyzs, positions, **kw):
        self.meshes[name] = {"positions": np.asarray(positions), **kw}

    def remove_by_name(self, name):
        self.removed.append(name)
        self.meshes.pop(name, None)

    def add_line_segments(self, *a, **kw):
        pass

    def add_label(self, *a, **kw):
        pass


def test_payload_cells_are_read_from_the_spec_as_plain_data():
    assert payload_cells({"modules": {"payload": {"cells": [[0, 0, 0], [1, 0, 0]], "mass_kg": 2.0}}}) == [
        (0, 0, 0),
        (1, 0, 0),
    ]
    assert payload_cells({"objective": {"payload_cells": [[2, 1, 0]]}}) == [(2, 1, 0)], "an older co-design spec"
    both = {"modules": {"payload": {"cells": [[0, 0, 0]]}}, "objective": {"payload_cells": [[0, 0, 0]]}}
    assert payload_cells(both) == [(0, 0, 0)]
    for spec in (None, {}, {"modules": None}, {"modules": {"payload": None}}, {"objective": {"payload_cells": []}}):
        assert payload_cells(spec) == [], spec
    odd = {"objective": {"payload_cells": [[0, 0], "x", [1, 2, 3.5], [True, 0, 0], [1, 1, 1]]}}
    assert payload_cells(odd) == [(1, 1, 1)], "what is not three integers is skipped, not raised"
    files = _files()
    spec = {"name": "plate", "algorithm": "diffsim-codesign", "modules": {"payload": {"cells": PLATE, "mass_kg": 1}}}
    run = RunData.from_json(DesignReport.of(PLATE_GRID.tolist()).to_json(), files["trajectories.json"], spec=spec)
    assert run.payload_cells == [tuple(c) for c in PLATE]
    assert RunData.from_json(files["design.json"], files["trajectories.json"]).payload_cells == []


def test_payload_cells_get_their_own_colour_and_the_actuator_stays_orange():
    vox = Voxels.from_grid(PLATE_GRID, [*PLATE, [1, 1, 1], [5, 5, 5]])  # the wheel unit and a cell outside: not payload
    cells = np.argwhere(PLATE_GRID > 0)
    on_plate = cells[:, 2] == 0
    assert vox.is_payload.tolist() == on_plate.tolist()
    colors = vox.colors_linear
    assert np.allclose(colors[vox.is_payload], srgb_to_linear(PAYLOAD_SRGB))
    assert np.allclose(colors[vox.types == 2], srgb_to_linear(ACTUATOR_SRGB))
    rest = ~vox.is_payload & (vox.types == 1)
    assert rest.sum() == 27 - 9 - 1 and np.allclose(colors[rest], srgb_to_linear(STRUCTURE_SRGB))
    assert not np.allclose(srgb_to_linear(PAYLOAD_SRGB), srgb_to_linear(STRUCTURE_SRGB))

    scene = _Scene()
    draw_satellite(scene, "/A", PLATE_GRID, payload=PLATE)
    m = scene.meshes
    assert len(m["/A/body/payload"]["positions"]) == 9 and m["/A/body/payload"]["opacity"] == PAYLOAD_OPACITY
    assert np.allclose(m["/A/body/payload"]["batched_colors"], srgb_to_linear(PAYLOAD_SRGB))
    assert PAYLOAD_OPACITY > STRUCTURE_OPACITY, "the plate less translucent than structure"
    assert len(m["/A/body/structure"]["positions"]) == 17
    assert np.allclose(m["/A/body/structure"]["batched_colors"], srgb_to_linear(STRUCTURE_SRGB))
    assert len(m["/A/body/voxels"]["positions"]) == 1 and m["/A/body/voxels"]["opacity"] is None
    assert np.allclose(m["/A/body/voxels"]["batched_colors"], srgb_to_linear(ACTUATOR_SRGB))
    assert len(m["/A/target/ghost"]["positions"]) == 27

    draw_satellite(scene, "/A", PLATE_GRID)  # redrawn without a payload: as before, no payload mesh
    assert "/A/body/payload" not in scene.meshes and "/A/body/payload" in scene.removed
    assert len(scene.meshes["/A/body/structure"]["positions"]) == 26
    assert np.allclose(scene.meshes["/A/body/structure"]["batched_colors"], srgb_to_linear(STRUCTURE_SRGB))


def test_no_payload_draws_as_before():
    vox, marked = Voxels.from_grid(GRID), Voxels.from_grid(GRID, [])
    assert vox.payload is None and not vox.is_payload.any() and marked.payload is None
    assert np.allclose(vox.colors_linear, marked.colors_linear)
    scene = _Scene()
    draw_satellite(scene, "/A", GRID)
    assert set(scene.meshes) == {"/A/body/voxels", "/A/body/structure", "/A/target/ghost"}
    assert not np.isclose(scene.meshes["/A/target/ghost"]["batched_colors"], srgb_to_linear(PAYLOAD_SRGB)).all(1).any()


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
    plate = {"name": "plate", "algorithm": "diffsim-codesign", "objective": {"payload_cells": PLATE}}
    design = DesignReport.of(PLATE_GRID.tolist()).to_json()
    with_payload = recording_bytes(design, files["trajectories.json"], spec_json=json.dumps(plate).encode())
    without = recording_bytes(design, files["trajectories.json"], spec_json=json.dumps({"name": "plate"}).encode())
    assert len(with_payload) > len(without), "the payload is a mesh of its own in the recording"


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
    # Run b carries a payload (an older co-design spec's form): its first cell is drawn as payload.
    (tmp_path / "b" / "spec.json").write_text(json.dumps({"name": "b", "objective": {"payload_cells": [[0, 0, 0]]}}))
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
        drawn = app.server.scene._handle_from_node_name  # viser 1.1.1 (pinned): the scene's nodes by name
        assert "/B/body/payload" in drawn and "/A/body/payload" not in drawn and "/A/body/voxels" in drawn
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
