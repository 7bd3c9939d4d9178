"""The ``.viser`` recording of a run's evaluation slews: a 3D replay that plays in viser's
static client (``index.html?playbackPath=.../evaluation.viser``) with no Python running.

The recording shows the designed satellite flown by the trained policy and, beside it, the
same satellite flown by the PD baseline on the same seeded slew, each with a ghost of its
target attitude; the recorded episodes follow one another with a short pause between
them. It is made from the stored ``design.json`` and ``trajectories.json`` alone, so the
worker, ``modsat train`` and ``modsat view --save`` all produce the same file.
"""

from __future__ import annotations

import contextlib
import io
import logging
import threading
from collections.abc import MutableMapping

import numpy as np

from .run import CONTROLLERS, RunData, sample_period
from .scene import draw_satellite, lay_out

log = logging.getLogger("modsat.viewer")

#: Name of the artefact in a job's file list and in a ``modsat train`` output directory.
RECORDING_NAME = "evaluation.viser"
#: Playback is subsampled to at most this many frames per second of simulated time.
MAX_FPS = 20.0

# One recording at a time per process: each needs its own throwaway viser server.
_lock = threading.Lock()


def _frames(episodes: list, max_fps: float) -> tuple[np.ndarray, float]:
    """Frame times of a set of episodes played together: (F,) s, and the frame period."""
    dt = sample_period(episodes)
    stride = max(1, int(round((1.0 / max_fps) / dt))) if dt > 0 else 1
    period = dt * stride
    end = max((e.t_s[-1] for e in episodes if len(e.t_s)), default=0.0)
    return np.arange(0.0, end + 1e-9, period), period


def recording_bytes(
    design_json,
    trajectories_json,
    *,
    spec_json=None,
    title: str | None = None,
    controllers: tuple[str, ...] = tuple(CONTROLLERS),
    max_episodes: int = 3,
    speed: float = 1.0,
    pause_s: float = 1.0,
    max_fps: float = MAX_FPS,
) -> bytes:
    """Bytes of a ``.viser`` file replaying the recorded evaluation slews of a run.

    Args:
        design_json, trajectories_json: the run's artefacts (bytes, str or decoded JSON).
        spec_json: optional ``spec.json``, for the run's name in the labels and its payload's cells.
        controllers: which of ``policy`` / ``pd_baseline`` to show, side by side.
        max_episodes: how many recorded slews to play, one after another.
        speed: playback speed (1 = real time of the simulated slew).
        pause_s: wall time between two slews.
    """
    import viser

    run = RunData.from_json(design_json, trajectories_json, spec=spec_json, title=title)
    shown = [c for c in controllers if run.episodes.get(c)] or [controllers[0]]
    n_ep = max([min(max_episodes, len(run.episodes.get(c, []))) for c in shown] + [0])
    with _lock:
        with contextlib.redirect_stdout(io.StringIO()):  # viser prints a banner even with verbose=False
            server = viser.ViserServer(host="127.0.0.1", port=0, verbose=False)
        try:
            scene = server.scene
            scene.set_up_direction("+z")
            sats = []
            for c in shown:
                sats.append(
                    draw_satellite(
                        scene, f"/{c}", run.grid, label=f"{run.title}: {CONTROLLERS[c]}", payload=run.payload_cells
                    )
                )
            server.initial_camera.position = lay_out(scene, [f"/{c}" for c in shown], sats)
            server.initial_camera.look_at = (0.0, 0.0, 0.0)
            rec = server.get_scene_serializer()
            for i in range(n_ep):
                eps = [run.episodes[c][i] if i < len(run.episodes.get(c, [])) else None for c in shown]
                live = [e for e in eps if e is not None and len(e.t_s)]
                if not live:
                    continue
                times, period = _frames(live, max_fps)
                for sat, e in zip(sats, eps):
                    if e is not None and len(e.t_s):
                        sat.set_attitude(e.q_BN[0], e.q_TN)
                rec.insert_sleep(pause_s)
                for t in times:
                    for sat, e in zip(sats, eps):
                        if e is not None and len(e.t_s):
                            sat.body.wxyz = e.q_BN[e.index_at(t + float(e.t_s[0]))]
                    rec.insert_sleep(period / speed)
            rec.insert_sleep(pause_s)
            return rec.serialize()
        finally:
            with contextlib.redirect_stdout(io.StringIO()):
                server.stop()


def recording_html(viser_bytes: bytes, dark_mode: bool = False) -> str:
    """One self-contained HTML page that plays a ``.viser`` recording (viser's client with the
    recording inlined, as ``StateSerializer.as_html`` builds it): open it from disk, no server."""
    import base64
    from pathlib import Path

    import viser

    client = (Path(viser.__file__).resolve().parent / "client" / "build" / "index.html").read_text()
    data = base64.b64encode(viser_bytes).decode("ascii")
    inject = (
        f'<script>window.__VISER_EMBED_DATA__="{data}";'
        f"window.__VISER_EMBED_CONFIG__={{darkMode:{'true' if dark_mode else 'false'}}};</script>"
    )
    head_end = client.index("</head>")
    return client[:head_end] + inject + client[head_end:]


def add_recording(files: MutableMapping[str, bytes]) -> bool:
    """Add ``evaluation.viser`` to a finished run's files (name -> bytes) if they hold
    ``design.json`` and ``trajectories.json``. A failure is logged, never raised: the
    recording is a convenience and must not cost the run its results."""
    if "design.json" not in files or "trajectories.json" not in files:
        return False
    try:
        files[RECORDING_NAME] = recording_bytes(
            files["design.json"], files["trajectories.json"], spec_json=files.get("spec.json")
        )
        return True
    except Exception:  # see the docstring
        log.exception("could not make the %s recording", RECORDING_NAME)
        return False
