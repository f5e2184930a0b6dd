"""`fovjax view`: the live viewer's command line. Every argument is checked before anything is
built; a mistake is one line on stderr and exit status 2."""

from __future__ import annotations

import argparse
import asyncio
import importlib.util
import logging
import math
import os
import socket
import sys
from pathlib import Path

SCENE_ALIASES = {"cornell": "cornell_box"}
MAX_EYE_PIXELS = 8192


def register(sub: argparse._SubParsersAction) -> None:
    p = sub.add_parser(
        "view",
        help="live foveated stereo viewer in the browser (gaze from the mouse or a tracker)",
        description="Serve a page that shows foveated stereo frames rendered continuously for the "
        "newest gaze: the mouse over either eye (the other eye's gaze follows from the rig's geometry) "
        "or a gaze source spec as `fovjax session --gaze` takes (synthetic:scanpath, replay:FILE, "
        "serial:PORT, pupil:HOST:PORT, ...). Keys on the page: arrows head yaw/pitch, 0 head reset, "
        "q/a fovea up/down, w/s periphery up/down, 1-5 the thesis's threshold pairs, m full vs "
        "foveated, v regions/samples view, p save the frame and its statistics. Needs the 'view' extra.",
    )
    p.add_argument("--scene", default="spheres", help="atrium, cornell, spheres, or a scene file (spheres)")
    p.add_argument("--triangles", type=int, default=262_000, help="atrium size (triangles)")
    p.add_argument("--gaze", default="mouse", help="'mouse' (default) or a gaze source spec")
    p.add_argument("--head", default="keys", help="'keys' (default) or a head source spec")
    p.add_argument("--width", type=int, default=320, help="pixels per eye (default 320)")
    p.add_argument("--height", type=int, default=256, help="pixels per eye (default 256)")
    p.add_argument("--fovea", type=float, default=5.0, help="fovea eccentricity in degrees (default 5)")
    p.add_argument("--periphery", type=float, default=10.0, help="periphery eccentricity (default 10)")
    p.add_argument("--spp", type=int, default=1, help="samples per pixel: 1, 4, 9, ... (default 1)")
    p.add_argument("--max-depth", type=int, default=5, help="reflection bounces (default 5)")
    p.add_argument("--backend", default="jax", choices=("jax", "embree"), help="ray traversal backend")
    p.add_argument("--seed", type=int, default=0, help="PRNG seed of the sampling (default 0)")
    p.add_argument("--host", default="127.0.0.1", help="address to listen on (default 127.0.0.1)")
    p.add_argument("--port", type=int, default=8000, help="port (default 8000; 0: any free port)")
    p.add_argument("--save-dir", default="fovjax-view", help="where the page's save key writes (fovjax-view)")
    p.add_argument("--open", action="store_true", help="open the page in a browser")
    p.add_argument("--verbose", action="store_true", help="log every client and ignored message")
    p.set_defaults(func=run)


def check_args(args) -> None:
    """Raise ValueError naming the first bad argument."""
    for name in ("width", "height"):
        value = getattr(args, name)
        if not 1 <= value <= MAX_EYE_PIXELS:
            raise ValueError(f"--{name} must be between 1 and {MAX_EYE_PIXELS} pixels per eye, got {value}")
    if args.spp < 1 or math.isqrt(args.spp) ** 2 != args.spp:
        raise ValueError(f"--spp must be a positive square (1, 4, 9, ...), got {args.spp}")
    for name in ("fovea", "periphery"):
        value = getattr(args, name)
        if not (math.isfinite(value) and 0 < value <= 90):
            raise ValueError(f"--{name} must be in (0, 90] degrees, got {value}")
    if not args.fovea < args.periphery:
        raise ValueError(f"--fovea must be smaller than --periphery, got {args.fovea} and {args.periphery}")
    if args.max_depth < 0:
        raise ValueError(f"--max-depth must be >= 0, got {args.max_depth}")
    if args.triangles < 1:
        raise ValueError(f"--triangles must be positive, got {args.triangles}")
    if not 0 <= args.port <= 65535:
        raise ValueError(f"--port must be in 0..65535 (0: any free port), got {args.port}")
    if args.backend == "embree" and importlib.util.find_spec("embreex") is None:
        raise ImportError("--backend embree needs embreex: pip install 'fovjax[embree]'")
    if Path(args.save_dir).exists() and not Path(args.save_dir).is_dir():
        raise ValueError(f"--save-dir {args.save_dir!r} is a file, not a directory")
    if not args.host.strip():
        raise ValueError("--host must not be empty")
    name = SCENE_ALIASES.get(args.scene, args.scene)
    from fovjax.scenes import BUILTIN

    if name not in BUILTIN and not Path(args.scene).is_file():
        raise ValueError(
            f"--scene {args.scene!r}: not a built-in scene ({', '.join(['cornell', *BUILTIN])}) "
            "nor an existing file"
        )
    from fovjax.devices import source_from_spec

    if args.gaze != "mouse":
        source_from_spec(args.gaze, "gaze")  # ValueError names the bad part of the spec
    if args.head != "keys":
        source_from_spec(args.head, "head")
    if importlib.util.find_spec("aiohttp") is None:
        raise ImportError("fovjax view needs aiohttp: pip install 'fovjax[view]'")
    _check_listen(args.host, args.port)


def _check_listen(host: str, port: int) -> None:
    """Fail now, not after the scene is built, when the address cannot be listened on."""
    try:
        infos = socket.getaddrinfo(host, port, type=socket.SOCK_STREAM, flags=socket.AI_PASSIVE)
    except socket.gaierror as err:
        raise ValueError(f"--host {host!r}: not an address of this machine ({err.strerror})") from None
    family, kind, proto, _, address = infos[0]
    with socket.socket(family, kind, proto) as probe:
        probe.setsockopt(socket.SOL_SOCKET, socket.SO_REUSEADDR, 1)  # as aiohttp does
        try:
            probe.bind(address)
        except OSError as err:
            raise OSError(f"cannot listen on {host}:{port}: {err.strerror or err}") from None


def _load_scene(args):
    import fovjax

    name = SCENE_ALIASES.get(args.scene, args.scene)
    if name in fovjax.scenes.BUILTIN:
        kwargs = {"triangles": args.triangles} if name == "atrium" else {}
        return fovjax.scenes.BUILTIN[name](**kwargs)
    return fovjax.load_scene(args.scene)


def run(args) -> int:
    from fovjax.devices import DeviceError

    try:
        check_args(args)
        return _run(args)
    except (ValueError, OSError, ImportError, DeviceError) as err:
        print(f"fovjax view: error: {err}", file=sys.stderr)
        return 2
    except KeyboardInterrupt:
        print("fovjax view: stopped", file=sys.stderr)
        return 0


def _run(args) -> int:
    import fovjax
    from fovjax.foveate import Foveation
    from fovjax.render import RenderConfig, StereoRig

    from ._renderer import LiveRenderer
    from ._server import Viewer

    logging.basicConfig(level=logging.WARNING, format="fovjax view: %(levelname)s: %(message)s")
    logging.getLogger("fovjax.view").setLevel(logging.INFO if args.verbose else logging.WARNING)
    scene = _load_scene(args)
    rig = StereoRig.from_pose(
        fovjax.scenes.default_camera(scene), eye_width=args.width, eye_height=args.height
    )
    renderer = LiveRenderer(
        scene,
        rig,
        Foveation(fovea_deg=args.fovea, periphery_deg=args.periphery, spp=args.spp),
        config=RenderConfig(max_depth=args.max_depth, backend=args.backend),
        gaze=None if args.gaze == "mouse" else args.gaze,
        head=None if args.head == "keys" else args.head,
        seed=args.seed,
    )
    # Devices first: an unreachable tracker is an error now, before anything is served.
    renderer.open()
    viewer = Viewer(renderer, host=args.host, port=args.port, save_dir=args.save_dir)
    try:
        code = asyncio.run(_serve(viewer, args.open))
    except KeyboardInterrupt:
        print("fovjax view: stopped", file=sys.stderr)
        code = 0
    if viewer.render_busy:
        # The render thread is inside XLA (a compile or a frame), which cannot be interrupted,
        # and finalising the interpreter around it aborts the process: leave at once.
        sys.stdout.flush()
        sys.stderr.flush()
        os._exit(code)
    return code


async def _serve(viewer, open_browser: bool) -> int:
    try:
        url = await viewer.start()
    except OSError as err:
        raise OSError(f"cannot listen on {viewer.host}:{viewer.port}: {err.strerror or err}") from None
    print(f"fovjax view: serving {url}  (Ctrl-C to stop; the first frame compiles for a while)", flush=True)
    if viewer.token is not None:
        print(
            f"fovjax view: listening on {viewer.host}, not loopback: the page needs the token in this URL"
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
    try:
        await viewer.frame_loop
    except Exception as err:
        print(f"fovjax view: error: rendering failed: {type(err).__name__}: {err}", file=sys.stderr)
        return 1
    finally:
        await viewer.stop()
    return 0
