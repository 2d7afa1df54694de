#!/usr/bin/env python3
"""Open the viewer the way a person does and check that it shows the scene.

Builds the demo room (``cylindersplat.scenes.demo_room``, ~19k Gaussians, no training) with three
input cameras and their panoramas, then

* ``server``: starts ``cylindersplat view room.ply --poses-file poses.json`` (a viser server on a free
  local port) and loads its page in headless Chromium;
* ``html``: writes ``cylindersplat view ... --html room.html`` and loads the file, no server;

waits until the splats are drawn (screenshots every second until most of the page is neither the page
background nor the loading state), saves ``viewer_<mode>.png`` and fails unless the picture has enough
non-background pixels and contrast. Needs the view extra (viser), Debian's chromium and the playwright
Python package (it drives the system browser; nothing is downloaded):
``bash scripts/install_optional.sh view && bash scripts/install_optional.sh browser``.

    python scripts/viewer_screenshot.py --out outputs/viewer_check            # both modes
    python scripts/viewer_screenshot.py --mode html --chromium /usr/bin/chromium
"""

from __future__ import annotations

import argparse
import json
import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

# Flags that keep headless Chromium off the network (no lookups to hang on) and off a GPU; WebGL then runs on
# SwiftShader, Chromium's software renderer (the two swiftshader flags allow it explicitly; playwright adds them too).
CHROMIUM_FLAGS = [
    "--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
    "--disable-background-networking",
    "--disable-component-update", "--disable-sync", "--enable-unsafe-swiftshader", "--use-angle=swiftshader",
]
VIEWPORT = {"width": 800, "height": 600}


def find_chromium(explicit: str | None) -> str | None:
    for candidate in (explicit, os.environ.get("CHROMIUM"), "/usr/bin/chromium", shutil.which("chromium"),
                      shutil.which("chromium-browser"), shutil.which("google-chrome")):
        if candidate and Path(candidate).is_file():
            return candidate
    return None


def build_demo(folder: Path, pano_height: int = 64) -> tuple[Path, Path]:
    """The demo room as a 3DGS PLY, and a poses.json of three cameras with their rendered panoramas."""
    import torch
    from PIL import Image

    from cylindersplat.gaussians import save_ply
    from cylindersplat.geometry import make_c2w
    from cylindersplat.render import render_equirect
    from cylindersplat.scenes import demo_room

    folder.mkdir(parents=True, exist_ok=True)
    room = demo_room()
    poses = torch.stack([make_c2w(translation=torch.tensor([x, 0.0, 0.3 * x])) for x in (-1.0, 0.0, 1.0)])
    panoramas = render_equirect(room, poses, pano_height, 2 * pano_height, background=(1.0, 1.0, 1.0)).rgb
    frames = []
    for i, (pose, rgb) in enumerate(zip(poses, panoramas)):
        name = f"pano_{i:02d}.png"
        Image.fromarray((rgb.clamp(0, 1) * 255 + 0.5).byte().permute(1, 2, 0).numpy()).save(folder / name)
        frames.append({"image": name, "c2w": pose.tolist()})
    (folder / "poses.json").write_text(json.dumps({"frames": frames}))
    return save_ply(room, folder / "room.ply"), folder / "poses.json"


def picture_stats(png: Path) -> dict:
    """Share of pixels that differ from the page background (the most common corner colour), and contrast."""
    from PIL import Image

    image = np.asarray(Image.open(png).convert("RGB"), dtype=np.int16)
    corners = np.concatenate([image[:8, -8:].reshape(-1, 3), image[-8:, :8].reshape(-1, 3),
                              image[-8:, -8:].reshape(-1, 3)])
    colours, counts = np.unique(corners, axis=0, return_counts=True)
    page = colours[counts.argmax()]
    white = np.array([255, 255, 255])
    differs = lambda colour: (np.abs(image - colour).max(axis=-1) > 24)  # noqa: E731
    return {
        "non_background_share": float((differs(page) & differs(white)).mean()),
        "std": float(image.std()),
        "distinct_colours": int(len(np.unique(image[::4, ::4].reshape(-1, 3) // 16, axis=0))),
    }


def looks_drawn(stats: dict, min_share: float, min_std: float) -> bool:
    return stats["non_background_share"] >= min_share and stats["std"] >= min_std and stats["distinct_colours"] >= 20


def shoot(url: str, out: Path, chromium: str, timeout: float, min_share: float, min_std: float) -> dict:
    """Load ``url`` in headless Chromium, screenshot every second until the scene looks drawn (or ``timeout``)."""
    from playwright.sync_api import sync_playwright

    console = []
    with sync_playwright() as p, tempfile.TemporaryDirectory(prefix="chromium-profile-") as profile:
        context = p.chromium.launch_persistent_context(
            profile, executable_path=chromium, headless=True, args=CHROMIUM_FLAGS, viewport=VIEWPORT)
        try:
            page = context.new_page()
            page.on("console", lambda message: console.append(message.text[:300]))
            start = time.monotonic()
            page.goto(url, wait_until="load", timeout=timeout * 1000)
            stats = {}
            while True:
                page.wait_for_timeout(1000)
                page.screenshot(path=str(out))
                stats = picture_stats(out)
                elapsed = time.monotonic() - start
                if looks_drawn(stats, min_share, min_std):
                    page.wait_for_timeout(1500)  # let sorting / progressive upload settle, then the final picture
                    page.screenshot(path=str(out))
                    stats = picture_stats(out)
                    break
                if elapsed > timeout:
                    break
            stats["seconds"] = round(time.monotonic() - start, 1)
        finally:
            context.close()
    webgl = [line for line in console if "WebGL" in line and "GL Driver" not in line]
    stats["webgl"] = webgl[0] if webgl else "(no WebGL message)"
    # viser 1.1's splat mesh has a 2-component "position" attribute (its quad), which three.js's bounding sphere
    # reads as NaN: one "computeBoundingSphere(): Computed radius is NaN" per page, from viser's client, not the data.
    stats["console_nan"] = [line[:120] for line in console if "NaN" in line]
    stats["drawn"] = looks_drawn(stats, min_share, min_std)
    return stats


def cylindersplat(*args: str) -> list[str]:
    return [sys.executable, "-m", "cylindersplat", *args]


def check_server(ply: Path, poses: Path, out: Path, chromium: str, timeout: float, **limits) -> dict:
    env = {**os.environ, "PYTHONUNBUFFERED": "1"}
    proc = subprocess.Popen(cylindersplat("view", str(ply), "--poses-file", str(poses), "--port", "0",
                                          "--duration", str(timeout + 120)),
                            stdout=subprocess.PIPE, stderr=subprocess.STDOUT, text=True, env=env)
    try:
        url, lines, deadline = None, [], time.monotonic() + 120
        while url is None and time.monotonic() < deadline:
            line = proc.stdout.readline()
            if not line:
                break
            lines.append(line.rstrip())
            found = re.search(r"viewer: (http://\S+)", line)
            url = found.group(1) if found else None
        if url is None:
            raise RuntimeError("the viewer did not start:\n" + "\n".join(lines[-20:]))
        print(f"server: {url}")
        return shoot(url, out, chromium, timeout, **limits)
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()


def check_html(ply: Path, poses: Path, out: Path, chromium: str, timeout: float, **limits) -> dict:
    html = out.with_suffix(".html")
    subprocess.run(cylindersplat("view", str(ply), "--poses-file", str(poses), "--html", str(html)), check=True)
    return shoot(html.resolve().as_uri(), out, chromium, timeout, **limits)


def main(argv: list[str] | None = None) -> int:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("--mode", choices=("server", "html", "both"), default="both")
    parser.add_argument("--out", type=Path, default=Path("outputs/viewer_check"), help="folder for the scene and PNGs")
    parser.add_argument("--chromium",
                        help="browser executable (default: $CHROMIUM, /usr/bin/chromium, chromium on PATH)")
    parser.add_argument("--timeout", type=float, default=90.0,
                        help="seconds to wait for the splats to draw (default 90)")
    parser.add_argument("--min-share", type=float, default=0.5,
                        help="least share of non-background pixels (default 0.5)")
    parser.add_argument("--min-std", type=float, default=20.0, help="least pixel standard deviation (default 20)")
    args = parser.parse_args(argv)

    chromium = find_chromium(args.chromium)
    if chromium is None:
        print("no chromium found: bash scripts/install_optional.sh browser (or --chromium PATH)", file=sys.stderr)
        return 2
    try:
        import playwright  # noqa: F401
        import viser  # noqa: F401
    except ModuleNotFoundError as exc:
        print(f"missing {exc.name}: bash scripts/install_optional.sh view && bash scripts/install_optional.sh browser",
              file=sys.stderr)
        return 2
    ply, poses = build_demo(args.out / "scene")
    limits = {"min_share": args.min_share, "min_std": args.min_std}
    failed = []
    for mode in ("server", "html") if args.mode == "both" else (args.mode,):
        png = args.out / f"viewer_{mode}.png"
        check = check_server if mode == "server" else check_html
        stats = check(ply, poses, png, chromium, args.timeout, **limits)
        print(f"{mode}: {png} {json.dumps(stats)}")
        if not stats["drawn"]:
            failed.append(mode)
    if failed:
        print(f"FAILED: the page looks blank in {', '.join(failed)} mode (see the PNGs)", file=sys.stderr)
        return 1
    print("ok: the viewer shows the scene")
    return 0


if __name__ == "__main__":
    sys.exit(main())
