"""``modsat serve``, ``modsat worker`` and ``modsat view`` (wired into server/cli/__init__.py by ``add_commands``)."""

from __future__ import annotations

import argparse
import os
import signal
import subprocess
import sys
import time

from pydantic import ValidationError


def add_commands(sub) -> None:
    """Add ``serve`` and ``worker`` to the ``modsat`` sub-command parser ``sub``."""
    from worker.args import add_worker_arguments

    s = sub.add_parser("serve", help="run the job service on this machine: REST API + N local workers")
    s.add_argument("--workers", type=int, default=1, metavar="N", help="local worker processes (default 1)")
    s.add_argument("--db", metavar="URL", help="job store URL (default: SQLite file in --data-dir)")
    s.add_argument("--data-dir", help="directory of the default SQLite database (default ./modsat-data)")
    s.add_argument("--host", help="address to listen on (default 127.0.0.1)")
    s.add_argument("--port", type=int, help="port to listen on (default 8000)")
    s.add_argument("--runner", help="what workers run: train (default), or noop / simulated / raise for tests")
    s.add_argument(
        "--viewer-port",
        type=int,
        metavar="PORT",
        help="port of the live 3D viewer (default 8080; 0 = any free port; a busy port moves up)",
    )
    s.add_argument("--no-viewer", action="store_true", help="do not run the live 3D viewer")
    s.set_defaults(func=_cmd_serve)

    v = sub.add_parser("view", help="show runs written by `modsat train --out DIR` in the 3D viewer (no service)")
    v.add_argument(
        "run_dirs",
        nargs="+",
        metavar="RUN_DIR",
        help="one run, or two to see them side by side (e.g. RL and GA); more can be picked in the viewer",
    )
    v.add_argument("--port", type=int, default=8080, help="port of the viewer (default 8080; a busy port moves up)")
    v.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    v.add_argument(
        "--save",
        metavar="FILE",
        help="write the first run's evaluation recording instead (FILE.viser, or FILE.html: one "
        "self-contained page) and exit",
    )
    v.set_defaults(func=_cmd_view)

    w = sub.add_parser("worker", help="run one worker that pulls jobs from the job store at --db URL")
    add_worker_arguments(w)
    w.set_defaults(func=_cmd_worker)


def _cmd_worker(args: argparse.Namespace) -> int:
    from worker.main import run_worker

    return run_worker(args)


def _stop_workers(procs: list[subprocess.Popen], grace_s: float) -> None:
    """SIGTERM (the training checkpoints, the job is requeued), then SIGKILL after ``grace_s``."""
    for p in procs:
        if p.poll() is None:
            p.send_signal(signal.SIGTERM)
    deadline = time.monotonic() + grace_s
    try:
        for p in procs:
            p.wait(timeout=max(0.1, deadline - time.monotonic()))
    except (subprocess.TimeoutExpired, KeyboardInterrupt):
        for p in procs:
            if p.poll() is None:
                p.send_signal(signal.SIGTERM)  # a second signal: stop without waiting for the training
        time.sleep(1.0)
        for p in procs:
            if p.poll() is None:
                p.kill()
            p.wait()


def _port_in_use(host: str, port: int) -> str | None:
    """Why (host, port) cannot be listened on, or None: checked before the workers and the
    viewer start, so that a second `modsat serve` stops with one clear line."""
    import socket

    if port == 0:
        return None
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as exc:
        return str(exc)
    family, kind, proto, _, addr = infos[0]
    with socket.socket(family, kind, proto) as sock:
        sock.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as uvicorn binds
        try:
            sock.bind(addr)
        except OSError as exc:
            return exc.strerror or str(exc)
    return None


def _cmd_serve(args: argparse.Namespace) -> int:
    import uvicorn

    from worker.store import JobStore

    from ..app import create_app
    from ..settings import ServerSettings

    if args.workers < 0 or args.workers > 256:
        print("modsat serve: --workers must be between 0 and 256", file=sys.stderr)
        return 2
    given = {
        "db_url": args.db,
        "data_dir": args.data_dir,
        "host": args.host,
        "port": args.port,
        "runner": args.runner,
        "viewer_port": args.viewer_port,
        "viewer": False if args.no_viewer else None,
    }
    try:
        settings = ServerSettings(**{k: v for k, v in given.items() if v is not None})
    except ValidationError as exc:
        print(f"modsat serve: invalid setting: {exc}", file=sys.stderr)
        return 2
    busy = _port_in_use(settings.host, settings.port)
    if busy:
        print(
            f"modsat serve: cannot listen on {settings.host}:{settings.port}: {busy} (is another `modsat serve` "
            "running?); choose another port with --port",
            file=sys.stderr,
        )
        return 1
    url = settings.resolved_db_url
    try:
        store = JobStore(url, busy_timeout_s=settings.sqlite_busy_timeout_s)
    except Exception as exc:  # a bad URL: say so and stop
        print(f"modsat serve: {exc}", file=sys.stderr)
        return 2
    try:
        store.create_schema()  # once, before the workers start
    except Exception as exc:  # say what is wrong with the database and stop
        print(f"modsat serve: cannot open the job store {store.url_for_humans}: {exc}", file=sys.stderr)
        return 1
    finally:
        store.dispose()

    shown_host = "127.0.0.1" if settings.host in ("0.0.0.0", "::") else settings.host
    base = f"http://{shown_host}:{settings.port}"
    print(f"modsat: job store  {store.url_for_humans}", flush=True)
    print(f"modsat: API        {base}/api  (OpenAPI: {base}/api/openapi.json)", flush=True)
    print(f"modsat: web UI     {base}/", flush=True)
    print(f"modsat: {args.workers} local worker(s); add more anywhere with: modsat worker --db URL", flush=True)
    if settings.host in ("0.0.0.0", "::") and not settings.allowed_hosts:
        print(
            "modsat: listening on every interface, but answering only to localhost names: set "
            "MODSAT_ALLOWED_HOSTS to the names or addresses others use to reach this machine",
            flush=True,
        )

    env = dict(os.environ, MODSAT_RUNNER=settings.runner)
    procs = [
        subprocess.Popen(
            [sys.executable, "-m", "worker", "--db", url, "--exit-with-parent", str(os.getpid())],
            env=env,
            start_new_session=True,
        )  # Ctrl-C reaches us; we stop them in order
        for _ in range(args.workers)
    ]

    def announce(where: str) -> None:
        print(f"modsat: 3D viewer  {where.replace('HOST', shown_host)}", flush=True)

    server = uvicorn.Server(
        uvicorn.Config(
            create_app(settings, announce=announce),
            host=settings.host,
            port=settings.port,
            log_level="info",
            timeout_graceful_shutdown=3,
        )
    )
    try:
        server.run()
    except (KeyboardInterrupt, SystemExit):  # uvicorn re-raises the Ctrl-C it handled, exits if it cannot bind
        pass
    finally:
        if procs:
            print(f"modsat: stopping {len(procs)} worker(s)...", flush=True)
            _stop_workers(procs, settings.cancel_grace_s + 5.0)
    print("modsat: stopped", flush=True)
    return 0 if server.started else 1


def _cmd_view(args: argparse.Namespace) -> int:
    """``modsat view RUN_DIR [RUN_DIR ...]``: the live viewer on local runs, until Ctrl-C."""
    from pathlib import Path

    from web.viewer.live import DirRuns, ViewerApp

    try:
        source = DirRuns(args.run_dirs)
    except (FileNotFoundError, ValueError) as exc:
        print(f"modsat view: {exc}", file=sys.stderr)
        return 2
    if args.save:
        from modsat_core.evaluation.run_folder import RunFolder
        from web.viewer.recording import recording_bytes, recording_html

        run = RunFolder(args.run_dirs[0])  # DirRuns has read it: design and trajectories are there
        data = recording_bytes(
            run.read("design.json"),
            run.read("trajectories.json"),
            spec_json=run.read_optional("spec.json"),
            title=run.name,
        )
        out = Path(args.save)
        if out.suffix.lower() == ".html":
            data = recording_html(data).encode()
        out.write_bytes(data)
        print(f"modsat view: wrote {out} ({len(data):,} bytes)")
        return 0
    if not 0 <= args.port <= 65535:
        print("modsat view: --port must be between 0 and 65535", file=sys.stderr)
        return 2
    app = ViewerApp(
        source,
        host=args.host,
        port=args.port,
        label="modsat view",
        allowed_hosts=os.environ.get("MODSAT_ALLOWED_HOSTS", ""),
    )
    shown = "127.0.0.1" if args.host in ("0.0.0.0", "::") else args.host
    names = " vs ".join(Path(p).name for p in args.run_dirs[:2])
    print(f"modsat view: {names} at http://{shown}:{app.port}/  (Ctrl-C to stop)", flush=True)
    try:
        while True:
            time.sleep(3600)
    except KeyboardInterrupt:
        pass
    finally:
        app.stop()
    return 0
