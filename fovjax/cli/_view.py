"""`fovjax view`: the live viewer's command line (with `--study`, the user-study player:
`fovjax.cli._view_study`). Every argument is checked first (`validate`,
with `fovjax.cli`'s checkers); errors and Ctrl-C are answered by `fovjax.cli.main` as for every
command (a bad argument: one line, exit status 2; a device or a missing extra: 1; Ctrl-C: 130,
naming the frames the page saved)."""

from __future__ import annotations

import argparse
import asyncio
import importlib.util
import logging
import signal
import socket
import threading

from fovjax import cli

from . import _view_study, _view_xr

SCENE_ALIASES = {"cornell": "cornell_box"}
# The viewer's own limit per eye (a live frame, drawn on one canvas twice as wide); larger
# frames are `fovjax render`'s. Below it the frame's memory is checked against the machine's, as
# every command's is (`cli.frame_size`).
MAX_EYE_PIXELS = 8192
DEFAULT_WIDTH, DEFAULT_HEIGHT = 320, 256


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "view",
        help="live foveated stereo viewer in the browser (gaze from the mouse or a tracker)",
        description="Serve a page that shows foveated stereo frames rendered continuously for the "
        "newest gaze: the mouse over either eye (the other eye's gaze follows from the rig's geometry) "
        "or a gaze source spec as `fovjax session --gaze` takes (synthetic:scanpath, replay:FILE, "
        "serial:PORT, pupil:HOST:PORT, ...). Keys on the page: arrows head yaw/pitch, 0 head reset, "
        "q/a fovea up/down, w/s periphery up/down, 1-5 the thesis's threshold pairs, m full vs "
        "foveated, v regions/samples view, p save the frame and its statistics. With --study "
        "pair|ramp|slider --participant ID -o DIR the page runs that test of the thesis's user study "
        "with a participant instead, recording the answers in DIR (see 'Running the study' in the "
        "documentation). With --xr the page shows the frames in a WebXR headset instead ('In a headset' in "
        "the documentation). Needs the 'view' extra.",
    )
    p.add_argument("--scene", default="spheres", help="atrium, cornell, spheres, or a scene file (spheres)")
    p.add_argument("--triangles", type=int, default=262_000, help="atrium size (triangles)")
    p.add_argument("--gaze", default="mouse", help="'mouse' (default) or a gaze source spec")
    p.add_argument("--head", default="keys", help="'keys' (default) or a head source spec")
    p.add_argument("--width", type=int, help=f"pixels per eye (default {DEFAULT_WIDTH})")
    p.add_argument("--height", type=int, help=f"pixels per eye (default {DEFAULT_HEIGHT})")
    p.add_argument("--fovea", type=float, default=5.0, help="fovea eccentricity in degrees (default 5)")

    cli.add_regions(p)
    p.add_argument("--periphery", type=float, default=10.0, help="periphery eccentricity (default 10)")
    p.add_argument(
        "--spp", type=int, help="samples per pixel: 1, 4, 9, ... (default 1; with --study 4, the thesis's)"
    )
    p.add_argument("--max-depth", type=int, default=5, help="reflection bounces (default 5)")
    cli.add_backend(p)
    p.add_argument(
        "--seed",
        type=int,
        help="PRNG seed of the sampling (default 0); with --study, the seed of a randomised trial order "
        "(default: the appendix's order)",
    )
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=8000, help="port (default 8000; 0: any free port)")
    p.add_argument("--save-dir", default="fovjax-view", help="where the page's save key writes (fovjax-view)")
    p.add_argument("--open", action="store_true", help="open the page in a browser")
    p.add_argument("--verbose", action="store_true", help="log every client and ignored message")
    _view_study.add_arguments(p)
    _view_xr.add_arguments(p)
    cli.add_size_check(p)
    p.set_defaults(func=run)


def validate(args) -> None:
    """Every argument of `fovjax view`, before a scene is built, a device opened or a port
    served: `fovjax.cli`'s checkers (`UsageError`, exit status 2), then the extras it needs
    (ImportError naming the `pip install`, exit status 1)."""
    from fovjax.view import MAX_THRESHOLD_DEG

    study_only = {"--participant": args.participant, "-o": args.output}
    given = [name for name, value in study_only.items() if value is not None]
    if args.study is None and given:
        raise cli.UsageError(f"{', '.join(given)}: only with --study pair|ramp|slider")
    _view_xr.validate(args)
    if args.spp is None:
        args.spp = _view_study.STUDY_SPP if args.study is not None else 1
    args.width = DEFAULT_WIDTH if args.width is None else args.width
    args.height = DEFAULT_HEIGHT if args.height is None else args.height
    cli.number(args.width, "--width", ge=1, le=MAX_EYE_PIXELS, integer=True)
    cli.number(args.height, "--height", ge=1, le=MAX_EYE_PIXELS, integer=True)
    cli.squares(args.spp, "--spp")
    # The page's keys move the thresholds within (0, 90] and keep the fovea inside the periphery.
    cli.number(args.fovea, "--fovea", gt=0, le=MAX_THRESHOLD_DEG)
    cli.number(args.periphery, "--periphery", gt=0, le=MAX_THRESHOLD_DEG)
    if not args.fovea < args.periphery:
        raise cli.UsageError(
            f"--fovea/--periphery {args.fovea:g},{args.periphery:g}: the fovea must be smaller than "
            "the periphery"
        )
    cli.number(args.max_depth, "--max-depth", ge=0, integer=True)
    cli.number(args.triangles, "--triangles", ge=1, integer=True)
    cli.seed(args.seed)
    if args.study is not None:
        _view_study.validate(args)
    cli.scene(args.scene)
    if args.gaze != "mouse":
        cli.source_spec(args.gaze, "gaze", "--gaze")
    if args.head != "keys":
        cli.source_spec(args.head, "head", "--head")
    cli.output(args.save_dir, "--save-dir", directory=True)
    if not args.host.strip():
        raise cli.UsageError(f"--host {args.host!r}: expected an address to listen on (e.g. 127.0.0.1)")
    cli.number(args.port, "--port", ge=0, le=65535, integer=True)
    _check_listen(args.host, args.port)
    cli.backend(args.backend)
    # The page's full/foveated toggle renders both; a study's clips (the reference and five
    # levels) are kept whole until they are encoded.
    kept = 6 * args.frames if args.study is not None and args.clips is None else 0
    cli.frame_size(args, args.width, args.height, args.spp, kept_images=kept)
    if importlib.util.find_spec("aiohttp") is None:
        raise ImportError("fovjax view needs aiohttp: pip install 'fovjax[view]'")


def _check_listen(host: str, port: int) -> None:
    """Fail now, not after the scene is built, when the address cannot be listened on."""
    from fovjax.cli import UsageError

    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as err:
        raise UsageError(f"--host {host!r}: not an address of this machine ({err.strerror})") from None
    family, kind, proto, _, address = infos[0]
    with socket.socket(family, kind, proto) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as aiohttp does
        try:
            probe.bind(address)
        except OSError as err:
            raise UsageError(
                f"--host/--port: cannot listen on {host}:{port}: {err.strerror or err}"
            ) from None


def _load_scene(args):
    import fovjax

    name = SCENE_ALIASES.get(args.scene, args.scene)
    if name in fovjax.scenes.BUILTIN:
        kwargs = {"triangles": args.triangles} if name == "atrium" else {}
        return fovjax.scenes.BUILTIN[name](**kwargs)
    return fovjax.load_scene(args.scene)


def run(args) -> int:
    validate(args)
    if args.study is not None:
        return _view_study.run(args, _load_scene)
    return _run(args)


def _run(args) -> int:
    import fovjax
    from fovjax.foveate import Foveation
    from fovjax.render import RenderConfig, StereoRig
    from fovjax.view import LiveRenderer, Viewer

    logging.basicConfig(level=logging.WARNING, format="fovjax view: %(levelname)s: %(message)s")
    logging.getLogger("fovjax.view").setLevel(logging.INFO if args.verbose else logging.WARNING)
    scene = _load_scene(args)
    foveation = cli.regions(
        Foveation(fovea_deg=args.fovea, periphery_deg=args.periphery, spp=args.spp), args, args.height
    )
    config = RenderConfig(max_depth=args.max_depth, backend=args.backend)
    on_save = lambda paths: cli.wrote(*paths)  # noqa: E731 (for the message on Ctrl-C)
    if args.xr:
        renderer, viewer = _view_xr.make(args, scene, foveation, config, on_save)
    else:
        rig = StereoRig.from_pose(
            fovjax.scenes.default_camera(scene), eye_width=args.width, eye_height=args.height
        )
        renderer = LiveRenderer(
            scene,
            rig,
            foveation,
            config=config,
            gaze=None if args.gaze == "mouse" else args.gaze,
            head=None if args.head == "keys" else args.head,
            seed=0 if args.seed is None else args.seed,
        )
        # Devices first: an unreachable tracker is an error now, before anything is served.
        renderer.open()
        viewer = Viewer(renderer, host=args.host, port=args.port, save_dir=args.save_dir, on_save=on_save)
    interrupted = threading.Event()
    try:
        asyncio.run(_serve(viewer, args.open, interrupted))
    except BaseException:
        if viewer.render_busy and not interrupted.is_set():
            # An error while the render thread is inside XLA (a compile or a frame), which
            # cannot be interrupted: finalising the interpreter around it aborts the process,
            # so the thread finishes its task first (Ctrl-C still ends the program at once).
            viewer.join_render_thread()
        raise
    if interrupted.is_set():
        # `fovjax.cli.main` says which frames were saved and exits with status 130; run as the
        # program it leaves at once (`os._exit`), safe while the render thread is inside XLA.
        raise KeyboardInterrupt
    return 0


async def _serve(viewer, open_browser: bool, interrupted: threading.Event) -> None:
    """Serve until Ctrl-C (sets `interrupted`) or until rendering cannot start (raised)."""
    from fovjax.devices import DeviceError

    loop = asyncio.get_running_loop()
    stop = asyncio.Event()

    def on_ctrl_c(signum, frame):
        # The first Ctrl-C (or SIGTERM) stops serving cleanly (clients told, sources closed, a
        # save in progress finished); the handlers before (`fovjax.cli`'s: leave at once) take
        # the next.
        interrupted.set()
        restore()
        loop.call_soon_threadsafe(stop.set)

    restore = _first_interrupt(on_ctrl_c)
    try:
        try:
            url = await viewer.start()
        except OSError as err:
            raise OSError(f"cannot listen on {viewer.host}:{viewer.port}: {err.strerror or err}") from None
        try:
            print(
                f"fovjax view: serving {url}  (Ctrl-C to stop; the first frame compiles for a while)",
                flush=True,
            )
            if viewer.token is not None:
                print(
                    f"fovjax view: listening on {viewer.host}, not loopback: the page needs the token in "
                    "this URL"
                    + (
                        " (put this machine's address in place of 0.0.0.0)"
                        if viewer.host in ("0.0.0.0", "::")
                        else ""
                    ),
                    flush=True,
                )
            if open_browser:
                import webbrowser

                webbrowser.open(url)
            stopped = asyncio.ensure_future(stop.wait())
            await asyncio.wait({viewer.frame_loop, stopped}, return_when=asyncio.FIRST_COMPLETED)
            stopped.cancel()
            if viewer.frame_loop.done() and not interrupted.is_set():
                err = viewer.frame_loop.exception()
                if err is None or isinstance(err, DeviceError):
                    raise err or RuntimeError("rendering stopped")
                raise RuntimeError(f"rendering failed: {type(err).__name__}: {err}") from err
        finally:
            await viewer.stop()
    finally:
        restore()


def _first_interrupt(handler):
    """`handler` for the next Ctrl-C or SIGTERM (`cli.INTERRUPT_SIGNALS`, those not ignored; in
    the main thread only); returns a function that puts the handlers before back (where
    `handler` is still in place)."""
    previous = {}
    if threading.current_thread() is threading.main_thread():
        for signum in cli.INTERRUPT_SIGNALS:
            before = signal.getsignal(signum)
            if before is not signal.SIG_IGN:
                previous[signum] = before
                signal.signal(signum, handler)

    def restore():
        for signum, before in previous.items():
            if signal.getsignal(signum) is handler:
                signal.signal(signum, before)

    return restore
