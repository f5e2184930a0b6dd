"""The screenshots of docs/tutorials/running-the-study.md: each test of `fovjax view --study`
in a headless Chromium (selenium), at the protocol's own timings, on real clips.

    python docs/_tools/study_screenshots.py [OUT_DIR]     # default docs/images

Renders the clips once (Cornell box, 2 x 160x128, SPP 4, 8 frames) into a scratch study folder,
then per test starts the command, fills the participant form and takes the screenshot: the pair
test during its foveated sequence, the ramp test at its question, the slider at its controls.
Needs chromium and chromedriver on PATH and the 'view' and 'dev' extras."""

from __future__ import annotations

import os
import re
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parents[2]
CLIP_ARGS = ["--scene", "cornell", "--width", "160", "--height", "128", "--frames", "8", "--spp", "4"]


def _browser():
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = shutil.which("chromium") or shutil.which("google-chrome")
    for flag in (
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--window-size=1100,860",
        "--hide-scrollbars",
    ):
        options.add_argument(flag)
    return webdriver.Chrome(options=options, service=Service(shutil.which("chromedriver")))


def _wait(driver, script, timeout=600):
    deadline = time.monotonic() + timeout
    while time.monotonic() < deadline:
        if driver.execute_script(script):
            return
        time.sleep(0.05)
    raise SystemExit(f"timed out waiting for {script}")


def _serve(test: str, participant: str, folder: Path):
    log = Path(tempfile.mkstemp(suffix=".log")[1])
    env = {**os.environ, "PYTHONPATH": str(ROOT)}
    argv = ["--study", test, "--participant", participant, "-o", str(folder), "--port", "0", *CLIP_ARGS]
    with log.open("w") as out:
        proc = subprocess.Popen(
            [sys.executable, "-m", "fovjax", "view", *argv], stdout=out, stderr=out, env=env
        )
    while (match := re.search(r"serving (http://\S+)", log.read_text())) is None:
        if proc.poll() is not None:
            raise SystemExit(log.read_text())
        time.sleep(0.2)
    print(log.read_text(), end="")
    return proc, match.group(1)


def _form_and_start(driver, url):
    from selenium.webdriver.common.by import By
    from selenium.webdriver.support.ui import Select

    driver.get(url)
    _wait(driver, "return window.fovjaxStudy && window.fovjaxStudy.phase === 'form'")
    for select in driver.find_elements(By.CSS_SELECTOR, "#form-fields select"):
        Select(select).select_by_index(len(Select(select).options) - 1)
    driver.find_element(By.ID, "consent").click()
    driver.find_element(By.ID, "form-submit").click()
    _wait(driver, "return window.fovjaxStudy.phase === 'instructions'")
    driver.find_element(By.ID, "start").click()


def main(out_dir: Path) -> None:
    out_dir.mkdir(parents=True, exist_ok=True)
    driver = _browser()
    with tempfile.TemporaryDirectory(prefix="fovjax-study-docs-") as d:
        folder = Path(d)
        shots = {
            "pair": "const s = window.fovjaxStudy; return s.segment && s.segment.kind === 'foveated'",
            "ramp": "return window.fovjaxStudy.phase === 'answering'",
            "slider": "return window.fovjaxStudy.phase === 'slider'",
        }
        try:
            for k, (test, ready) in enumerate(shots.items()):
                proc, url = _serve(test, f"doc{k + 1}", folder)
                try:
                    _form_and_start(driver, url)
                    _wait(driver, ready)
                    time.sleep(0.3 if test == "pair" else 0.1)
                    path = out_dir / f"study_{test}.png"
                    driver.save_screenshot(str(path))
                    print(f"wrote {path}")
                finally:
                    proc.terminate()
                    proc.wait(30)
        finally:
            driver.quit()


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else ROOT / "docs" / "images")
