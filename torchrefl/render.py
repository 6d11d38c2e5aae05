"""python -m torchrefl.render RUN_DIR [--camera SPEC] [--light SPEC] [--intensity Y [Y Y]] --out FILE.png | FOLDER

The fitted object of a finished run (torchrefl.load_run) seen by a camera under a light, with cast shadows and, for
a radiosity or photon run, the interreflection its level computes (torchrefl.report.relight), written as a PNG; with
--turntable N, N frames of the object turning under the fixed light and an animated GIF
(torchrefl.report.turntable). Camera and light specifications:
torchrefl.report.render_specs. Exit status: 0 done, 2 a named error, 130 interrupted.
"""

from __future__ import annotations

import argparse
import sys

import torch

from torchrefl.errors import OutputError, command_status
from torchrefl.report.render_specs import CAMERA_FORMS, LIGHT_FORMS, parse_camera, parse_light
from torchrefl.report.run_result import load_run
from torchrefl.report.turntable import (
    ENCODINGS,
    check_output_file,
    check_output_folder,
    turntable,
    write_image,
    write_turntable,
)

EXAMPLES = """examples:
  python -m torchrefl.render outputs/default --out relit.png
  python -m torchrefl.render outputs/default --camera "orbit 30 20 250" --light "point 100 150 200" --out relit.png
  python -m torchrefl.render outputs/mesh_views --camera outputs/mesh_views/capture/cameras.json:cam05 \\
      --light outputs/mesh_views/capture/lights.json:L01 --encoding linear16 --out cam05_L01.png
  python -m torchrefl.render outputs/diligent_ball --camera photographs --light "dir 0.3 0.4 0.866" --out ball.png
  python -m torchrefl.render outputs/default --turntable 36 --light "orbit 45 35" --out turntable/
"""


def _size(text: str) -> tuple[int, int]:
    w, _, h = text.partition("x")
    try:
        width, height = int(w), int(h)
    except ValueError:
        width = height = 0
    if width < 1 or height < 1:
        raise argparse.ArgumentTypeError(f"{text!r}: expected WIDTHxHEIGHT in pixels, e.g. 512x512")
    return width, height


def parser() -> argparse.ArgumentParser:
    p = argparse.ArgumentParser(
        prog="python -m torchrefl.render",
        description="Relight a finished run: the image of the fitted object from a camera under a point or "
        "directional light, with cast shadows and the interreflection of the run's level, in the fit's units; or a "
        "turntable.",
        epilog=EXAMPLES,
        formatter_class=argparse.RawDescriptionHelpFormatter,
    )
    p.add_argument("run", help="the run folder (output.dir of python -m torchrefl.train)")
    p.add_argument(
        "--camera",
        default=None,
        help=f"{CAMERA_FORMS}; degrees and the run's units (mm); default: 'orbit 30 20' "
        "('photographs' for photometric stereo)",
    )
    p.add_argument(
        "--light",
        default=None,
        help=f"{LIGHT_FORMS}; default: 'orbit 60 35' ('dir 0 0 1' for photometric stereo)",
    )
    p.add_argument(
        "--intensity",
        type=float,
        nargs="+",
        default=None,
        help="the light's radiant intensity, one or three (RGB) numbers, the capture's units (full range x mm^2 for "
        "a point light); default: the light file's, else a white surface facing the light reads 0.8 of full range",
    )
    p.add_argument("--out", required=True, help="the PNG to write, or with --turntable the folder for the frames")
    p.add_argument("--turntable", type=int, default=None, metavar="N", help="N frames of a full turn, and a GIF")
    p.add_argument("--size", type=_size, default=(512, 512), help="an orbit camera's image, WIDTHxHEIGHT px")
    p.add_argument("--supersample", type=int, default=2, help="K x K rays per pixel (default 2)")
    p.add_argument("--no-shadows", action="store_true", help="no shadow rays (every light reaches every point)")
    p.add_argument("--nearest", action="store_true", help="the nearest texel's estimate instead of bilinear")
    p.add_argument(
        "--no-interreflection",
        action="store_true",
        help="direct light and cast shadows only (default: a radiosity or photon run adds the interreflection its "
        "level computes for the light)",
    )
    p.add_argument("--encoding", choices=ENCODINGS, default="srgb8", help="8-bit sRGB (default) or 16-bit linear")
    p.add_argument("--exposure", type=float, default=1.0, help="multiply the values before encoding (default 1)")
    p.add_argument("--threads", type=int, default=2, help="CPU threads for Embree and torch (default 2)")
    p.add_argument("--overwrite", action="store_true", help="replace an existing image or turntable")
    p.add_argument("--quiet", action="store_true", help="no progress bar")
    return p


def main(argv=None) -> int:
    args = parser().parse_args(argv)

    def work() -> int:
        if args.turntable is None:
            out = check_output_file(args.out, args.overwrite)
        else:
            out = check_output_folder(args.out, args.overwrite)
        if args.threads < 1 or args.supersample < 1 or not args.exposure > 0:
            raise OutputError("--threads and --supersample must be >= 1 and --exposure > 0")
        torch.set_num_threads(args.threads)
        run = load_run(args.run)
        scene = run.scene
        ps = run.units == "px"
        camera = parse_camera(args.camera or ("photographs" if ps else "orbit 30 20"), run, scene, *args.size)
        intensity = None if args.intensity is None else args.intensity
        light = parse_light(args.light or ("dir 0 0 1" if ps else "orbit 60 35"), run, scene, intensity)
        options = dict(
            supersample=args.supersample,
            shadows=not args.no_shadows,
            interpolation="nearest" if args.nearest else "bilinear",
            interreflection=False if args.no_interreflection else None,
            progress=not args.quiet,
        )
        if args.turntable is None:
            image = run.render(camera=camera, light=light, **options)
            write_image(out, image.image, args.encoding, args.exposure)
            print(f"wrote {out} ({image.image.shape[1]} x {image.image.shape[0]} px)")
            return 0
        frames = turntable(run, camera, light, args.turntable, scene, **options)
        files = write_turntable(out, frames, args.encoding, args.exposure)
        print(f"wrote {len(files.frames)} frames and {files.gif}")
        return 0

    return command_status(work)


if __name__ == "__main__":
    sys.exit(main())
