"""Whose is the viewer page's "computeBoundingSphere(): Computed radius is NaN"? (docs/viewer.md)

Writes two static viser pages, one with a single clean Gaussian (centre 0, covariance 0.01 I, opacity 1; nothing
degenerate) and one with no splat (a coordinate frame only), opens each in headless Chromium and prints the
console messages that mention NaN. The first has the message, the second not: it comes with viser's splat mesh,
whose "position" attribute is a 2-component quad (viser/client/src/Splatting/GaussianSplatsHelpers.ts,
createGaussianMeshProps) that three.js's bounding sphere reads as 3-component, whatever the data.

    python scripts/viser_nan_probe.py   # needs viser, playwright and chromium
                                        # (scripts/install_optional.sh view/browser)
"""

import sys
import tempfile
from pathlib import Path

import numpy as np

FLAGS = ["--headless", "--no-sandbox", "--disable-gpu", "--no-first-run", "--disable-background-networking"]


def page(with_splat: bool) -> str:
    import viser

    server = viser.ViserServer(port=0, verbose=False)
    try:
        if with_splat:
            server.scene.add_gaussian_splats("/splat", centers=np.zeros((1, 3), np.float32),
                                             covariances=np.eye(3, dtype=np.float32)[None] * 0.01,
                                             rgbs=np.full((1, 3), 0.5, np.float32),
                                             opacities=np.ones((1, 1), np.float32))
        else:
            server.scene.add_frame("/frame")
        return server.scene.as_html()
    finally:
        server.stop()


def main() -> int:
    from playwright.sync_api import sync_playwright

    chromium = sys.argv[1] if len(sys.argv) > 1 else "/usr/bin/chromium"
    with sync_playwright() as p, tempfile.TemporaryDirectory() as folder:
        for with_splat, label in ((True, "one clean splat"), (False, "no splat")):
            path = Path(folder) / f"page_{with_splat}.html"
            path.write_text(page(with_splat))
            browser = p.chromium.launch(executable_path=chromium, headless=True, args=FLAGS)
            console = []
            tab = browser.new_page()
            tab.on("console", lambda message: console.append(message.text[:120]))
            tab.goto(path.as_uri())
            tab.wait_for_timeout(12000)  # the page decodes its scene and draws a few frames
            browser.close()
            print(f"{label}: {[line for line in console if 'NaN' in line] or 'no NaN message'}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
