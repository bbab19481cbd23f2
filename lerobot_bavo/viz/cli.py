"""`bavo-view`: one BAVO episode in 3-D, in rerun (https://rerun.io).

Shows one episode of a BAVO dataset (a local root or a Hub repo id), or one episode that
`bavo-eval --rerun DIR` recorded, on rerun's timelines `frame_index` and `time` (seconds):
the base-frame coloured point cloud, the active camera (pinhole frustum placed by
`observation.camera_pose`) with its path so far, the RGB frame, the occluder panel while an
occlusion event is active, the target's visibility, the task progress and milestone flags as
time series with the occlusion events as markers, and optionally the 4D teacher's query points
(--teacher) and a relation heat map for one point (--relation-point). Everything is read from the
dataset or the recording; nothing is simulated.

Modes (one of):
  --save FILE.rrd  write a rerun recording and exit (the default, for headless machines: FILE
                   defaults to outputs/view/<dataset>_episode<k>.rrd); open it anywhere with
                   `rerun FILE.rrd` or `bavo-view --rrd FILE.rrd --web`
  --web            serve rerun's web viewer (http://localhost:<--web-port>) until Ctrl-C, with
                   rerun's CLI bound to --bind: 127.0.0.1 by default, so only this machine can open
                   it (over ssh, forward both --web-port and --grpc-port); --bind 0.0.0.0 opens both
                   ports to the network (anyone who can reach them sees the recording)
  --spawn          open rerun's native viewer (needs a display)

Examples:
  bavo-view --root outputs/datasets/bavo_cube_handoff --episode 3
  bavo-view --repo-id <user>/bavo_cube_handoff --episode 3 --web --teacher --relation-point 0
  bavo-eval --policy expert --tasks cube_handoff --conditions stage --episodes 1 \\
      --output-dir outputs/eval/x --rerun outputs/eval/x/videos
  bavo-view --rrd outputs/eval/x/videos/cube_handoff_stage_seed1000.rrd --web
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path

from lerobot_bavo.viz.serve import DEFAULT_BIND


def build_parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(prog="bavo-view", description=__doc__,
                                formatter_class=argparse.RawDescriptionHelpFormatter)
    src = p.add_argument_group("what to show (a dataset episode, or a recording)")
    src.add_argument("--root", type=Path, default=None, help="local dataset root (LeRobot v3.0 BAVO dataset)")
    src.add_argument("--repo-id", default=None,
                     help="Hub dataset repo id; its files are fetched into --root (default: LeRobot's cache)")
    src.add_argument("--episode", type=int, default=0, help="episode index (default 0)")
    src.add_argument(
        "--rrd", type=Path, default=None, help="an .rrd file (e.g. written by bavo-eval --rerun)"
    )
    mode = p.add_argument_group("mode (default --save)").add_mutually_exclusive_group()
    mode.add_argument("--save", type=Path, default=None, metavar="FILE.rrd",
                      help="write a rerun recording (default mode; default file outputs/view/<name>.rrd)")
    mode.add_argument("--web", action="store_true", help="serve rerun's web viewer until Ctrl-C")
    mode.add_argument("--spawn", action="store_true", help="open rerun's native viewer")
    opt = p.add_argument_group("options")
    opt.add_argument(
        "--web-port", type=int, default=9090, help="web viewer port (default 9090; 0: a free one)"
    )
    opt.add_argument("--grpc-port", type=int, default=9876,
                     help="port of the data server the web viewer reads (default 9876; 0: a free one)")
    opt.add_argument(
        "--bind",
        default=DEFAULT_BIND,
        metavar="ADDR",
        help=f"address --web listens on (default {DEFAULT_BIND}: this machine only; 0.0.0.0 or :: "
        "opens it to the network)",
    )
    opt.add_argument("--teacher", action="store_true",
                     help="also show the teacher's query points at t and their answers at t + 15 (arrows)")
    opt.add_argument(
        "--relation-point",
        type=int,
        default=None,
        metavar="I",
        help="also show the teacher's relation change dR of point I to every point as a heat map",
    )
    opt.add_argument(
        "--no-images", action="store_true", help="skip the RGB frames (smaller, faster recordings)"
    )
    opt.add_argument("--last-frame", type=int, default=None, metavar="K",
                     help="show frames 0..K only (the viewer then opens at frame K)")
    return p


def dataset_root(root: Path | None, repo_id: str | None, episode: int) -> Path:
    """A local root holding the episode; a repo id's files are fetched with LeRobot (meta, one episode)."""
    if repo_id is None or (root is not None and (Path(root) / "meta" / "info.json").is_file()):
        return root
    if root is None:
        from lerobot.utils.constants import HF_LEROBOT_HOME

        root = HF_LEROBOT_HOME / repo_id
    local = Path(root)
    if not (local / "meta" / "info.json").is_file():
        from lerobot.datasets.lerobot_dataset import LeRobotDataset

        LeRobotDataset(repo_id, root=local, episodes=[episode])  # downloads meta and this episode's files
    return local


def _source_recording(args):
    """(recording stream, default name) for the chosen source, logged lazily by the mode."""
    if args.rrd is not None:
        return None, args.rrd.stem
    from lerobot_bavo.viz.episode import load_dataset_episode

    root = dataset_root(args.root, args.repo_id, args.episode)
    ep = load_dataset_episode(root, args.episode, video=not args.no_images)
    if args.last_frame is not None:
        ep = ep.head(args.last_frame + 1)
    return ep, f"{Path(root).name}_episode{args.episode}"


def main(argv: list[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_args(argv)
    if (args.root is None and args.repo_id is None) == (args.rrd is None):
        parser.error("give a dataset (--root or --repo-id, with --episode) or a recording (--rrd), not both")
    if args.rrd is not None and not args.rrd.is_file():
        parser.error(f"--rrd {args.rrd} is not a file")
    if args.episode < 0:
        parser.error(f"--episode must be >= 0, got {args.episode}")
    if args.rrd is not None and args.save is not None:
        parser.error("--rrd is already a recording: use --web or --spawn to view it")
    if args.last_frame is not None and (args.last_frame < 0 or args.rrd is not None):
        parser.error("--last-frame needs a dataset episode and a frame index >= 0")
    for name in ("web_port", "grpc_port"):
        if not 0 <= getattr(args, name) <= 65535:
            parser.error(f"--{name.replace('_', '-')} must be a port number in 0..65535 (0: a free one)")
    t0 = time.perf_counter()
    try:
        ep, name = _source_recording(args)
    except (FileNotFoundError, ValueError) as e:
        print(f"bavo-view: {e}", file=sys.stderr)
        return 2
    kw = dict(teacher=args.teacher, relation_point=args.relation_point, images=not args.no_images)
    if ep is not None and args.relation_point is not None and not 0 <= args.relation_point < ep.n_points:
        parser.error(
            f"--relation-point {args.relation_point} is out of range: the clouds have {ep.n_points} points"
        )

    if not args.web and not args.spawn:
        from lerobot_bavo.viz.log import write_rrd

        path = args.save or Path("outputs") / "view" / f"{name}.rrd"
        write_rrd(ep, path, **kw)
        print(
            f"bavo-view: wrote {path} ({ep.length} frames, {path.stat().st_size / 1e6:.1f} MB) in "
            f"{time.perf_counter() - t0:.2f} s; open it with `rerun {path}` or `bavo-view --rrd {path} --web`"
        )
        return 0
    if args.web:
        return _web(args, ep, name, kw)
    return _spawn(args, ep, kw)


def _web(args, ep, name: str, kw) -> int:
    """Serve the recording (the --rrd file, or the episode written to a temporary .rrd) with rerun's CLI on
    --bind (`viz.serve`: why not the SDK's serve_grpc) until Ctrl-C or SIGTERM; the server never outlives
    us."""
    import signal
    import tempfile

    from lerobot_bavo.viz.serve import (
        ServeError,
        client_host,
        free_port,
        send_recording,
        start_server,
        stop,
        viewer_url,
    )

    def terminate(signum, frame):  # SIGTERM: leave through the finally below, which stops the server
        raise SystemExit(128 + signum)

    with tempfile.TemporaryDirectory(prefix="bavo-view-") as tmp:
        rrd = args.rrd
        if rrd is None:
            from lerobot_bavo.viz.log import write_rrd

            rrd = write_rrd(ep, Path(tmp) / f"{name}.rrd", **kw)
        try:
            grpc_port = free_port(args.bind, args.grpc_port)
            web_port = free_port(args.bind, args.web_port)
            if web_port == grpc_port:  # two picks of port 0 can coincide once the first is released
                web_port = free_port(args.bind, 0)
            child, grpc_url = start_server(args.bind, web_port, grpc_port, Path(tmp) / "rerun.log")
        except ServeError as e:
            print(f"bavo-view: {e}", file=sys.stderr)
            return 2
        try:
            send_recording(Path(rrd), grpc_url)
        except BaseException as e:
            stop(child)
            if not isinstance(e, ServeError):
                raise
            print(f"bavo-view: {e}", file=sys.stderr)
            return 2
        url = viewer_url(client_host(args.bind), web_port, grpc_port)
        try:
            previous = signal.signal(signal.SIGTERM, terminate)
        except ValueError:  # not the main thread (an embedding caller): SIGTERM then just ends the process,
            previous = None  # and the server with it (`serve.start_server` ties it to us)
        try:
            local = args.bind in ("127.0.0.1", "::1", "localhost")
            where = "this machine only" if local else f"bound to {args.bind}: reachable from the network"
            print(f"bavo-view: serving the web viewer at {url} ({where}; Ctrl-C to stop)", flush=True)
            code = child.wait()
            print(f"bavo-view: rerun's server exited ({code})", file=sys.stderr)
            return 1
        except KeyboardInterrupt:
            return 0
        finally:
            if previous is not None:
                signal.signal(signal.SIGTERM, previous)
            stop(child)


def _spawn(args, ep, kw) -> int:
    import rerun as rr

    from lerobot_bavo.viz.log import APPLICATION_ID, blueprint, log_episode

    rec = rr.RecordingStream(APPLICATION_ID)
    rec.spawn(default_blueprint=blueprint())
    if ep is None:
        from rerun.experimental import RrdReader, send_chunks

        send_chunks(RrdReader(args.rrd).stream(), recording=rec)
    else:
        rec.send_recording_name(ep.name)
        log_episode(rec, ep, **kw)
    rec.flush()
    return 0


if __name__ == "__main__":
    sys.exit(main())
