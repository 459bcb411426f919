"""faceanim view: a local browser viewer and editor for a .glb or .vrm file (faceanim.viewer)."""

from __future__ import annotations

import sys
from pathlib import Path

from faceanim.cli.commands import HELP
from faceanim.cli.common import CommandError, _arg_type, check_outputs
from faceanim.errors import shown

PORT = _arg_type("--port", 0, 65535, integer=True)


def _cmd_view(args) -> None:
    import signal
    import threading

    from faceanim.viewer.server import (
        MAX_PHOTOS,
        Viewer,
        ViewerServer,
        check_model,
        check_photo,
        check_vendor,
    )

    model = check_model(args.file)
    check_vendor(vrm=model.kind == "vrm")
    if len(args.photo or []) > MAX_PHOTOS:
        raise CommandError(f"give --photo at most {MAX_PHOTOS} times (front, side, side2)")
    photos = [check_photo(p) for p in args.photo or []]
    save = Path(args.save_points) if args.save_points else None
    if save is not None:
        if save.suffix.lower() != ".json":
            raise CommandError(f"--save-points '{shown(save, 80, tail=True)}' must end in .json")
        inputs = [model.path.resolve(), *(p.path.resolve() for p in photos)]
        if model.sound:
            inputs.append(model.sound.resolve())
        if save.resolve() in inputs:
            raise CommandError(f"--save-points '{shown(save, 80, tail=True)}' is also an input; give it its own path")
        check_outputs(save)
    server = ViewerServer(Viewer(model, photos, save), args.port)
    previous = signal.signal(signal.SIGTERM, signal.default_int_handler)  # SIGTERM stops as Ctrl-C does
    try:  # from here any stop (Ctrl-C, SIGTERM, SIGHUP) is the normal end: exit 0
        url = server.url
        print(f"faceanim view: {model.path.name} ({model.kind}) at {url}  (Ctrl-C to stop)", flush=True)
        if not args.no_browser:
            import webbrowser

            threading.Thread(target=webbrowser.open, args=(url,), daemon=True).start()
        server.serve_forever(poll_interval=0.2)
    except KeyboardInterrupt:
        from faceanim.errors import STOPS

        STOPS.clear()  # a stop is how the viewer ends: exit 0
        print("faceanim view: stopped", file=sys.stderr, flush=True)
    finally:
        signal.signal(signal.SIGTERM, previous)
        server.server_close()


def register(sub) -> None:
    p = sub.add_parser("view", help=HELP["view"],
                       description="Serve a local page (127.0.0.1 only; three.js from the package, works "
                                   "offline): orbit camera, a slider per morph target grouped by set (ARKit, "
                                   "visemes, AUs, emotions, FAPs), play/pause and scrub of the animations with "
                                   "their sound, and a panel to pick points on the mesh or on a photo and save "
                                   "them as the JSON 'faceanim landmarks --from' or 'faceanim photo --points' "
                                   "reads. Runs until Ctrl-C.")
    p.add_argument("file", metavar="FILE", help="the model: .glb (e.g. from faceanim demo, say, arkit play, "
                                                "photo --rig) or .vrm")
    p.add_argument("--port", type=PORT, default=8760, help="port on 127.0.0.1 (0: any free port)")
    p.add_argument("--no-browser", action="store_true", help="print the URL only; do not open a browser")
    p.add_argument("--photo", action="append", metavar="IMAGE",
                   help="a photo (JPEG or PNG) to pick points on for 'faceanim photo --points'; give up to three "
                        "(front, side, side2)")
    p.add_argument("--save-points", metavar="JSON",
                   help="where the page's Save button writes the picked points (this file only; it is "
                        "replaced at each save); without it the page only downloads them")
    p.set_defaults(func=_cmd_view)
