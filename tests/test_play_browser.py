"""`fbcpr play` in a real browser: the command serves its page, headless Chromium (the system's, software WebGL)
opens it, a reward prompt is picked on the page, the body moves and the reward plot updates, and a broken clip
and an unknown task show the package's message while the body keeps its prompt.

Set FBCPR_PLAY_SCREENSHOT=docs/img/play.png to refresh the documentation's screenshot (else it goes to tmp)."""
from __future__ import annotations

import os
import re
import shutil
import socket
import subprocess
import sys
import time
from pathlib import Path

import pytest
from PIL import Image, ImageChops
from playwright.sync_api import Locator, Page, expect, sync_playwright

ROOT = Path(__file__).resolve().parents[1]
CHROMIUM_ARGS = ["--use-gl=swiftshader", "--enable-unsafe-swiftshader", "--no-sandbox"]
PELVIS = re.compile(r"pelvis \(x, y, z\) = \((-?[\d.]+), (-?[\d.]+), (-?[\d.]+)\) m")


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module")
def server(tmp_path_factory):
    """`fbcpr play` on a free port, with a data folder that holds one broken clip; yields the page's address."""
    data = tmp_path_factory.mktemp("data")
    (data / "clips").mkdir()
    (data / "clips" / "broken.npz").write_bytes(b"not a clip archive")
    env = {**os.environ, "FBCPR_DATA": str(data), "OMP_NUM_THREADS": "1", "PYTHONUNBUFFERED": "1"}
    log = data / "play.log"  # a file, not a pipe: a server writing to a pipe nobody reads would block
    with log.open("w") as out:
        proc = subprocess.Popen([sys.executable, "-m", "fbcpr", "play", "--port", str(free_port())], cwd=ROOT,
                                env=env, stdout=out, stderr=subprocess.STDOUT)
    found, deadline = None, time.monotonic() + 60
    while found is None and time.monotonic() < deadline and proc.poll() is None:
        time.sleep(0.2)
        found = re.search(r"open (http://127\.0\.0\.1:\d+)", log.read_text())
    try:
        assert found is not None, "fbcpr play printed no address:\n" + log.read_text()
        yield found.group(1)
    finally:
        proc.terminate()
        proc.wait(timeout=20)


def para(page: Page, text: str) -> Locator:
    """The page's paragraph (a markdown widget's text) that contains `text`."""
    return page.locator("p").filter(has_text=text)


def field(page: Page, label: str) -> Locator:
    """The text input of the viser text widget labelled `label`: the first input after the label."""
    return page.locator(f"xpath=//*[normalize-space(text())='{label}']/following::input[1]")


def readout(page: Page) -> tuple[tuple[float, ...], str]:
    text = para(page, "pelvis (x, y, z)").inner_text()
    found = PELVIS.search(text)
    assert found, text
    return tuple(float(v) for v in found.groups()), text


def pick(page: Page, label: str, option: str) -> None:
    page.get_by_role("combobox", name=label).click()
    page.get_by_role("option", name=option, exact=True).click()


def test_play_page_prompts_the_running_body(server, tmp_path):
    chromium = shutil.which("chromium") or shutil.which("chromium-browser")
    assert chromium, "the browser test needs Debian's chromium (.ci/run installs it: apt-get install chromium)"
    with sync_playwright() as pw:
        browser = pw.chromium.launch(executable_path=chromium, args=CHROMIUM_ARGS)
        page = browser.new_page(viewport={"width": 960, "height": 600})
        page.goto(server)
        expect(para(page, "z from:")).to_contain_text("move-ego-0-0", timeout=30_000)

        field(page, "Search").fill("move-ego-0-2")
        pick(page, "Task", "move-ego-0-2")
        page.get_by_role("button", name="Prompt reward").click()
        expect(para(page, "z from:")).to_contain_text("reward move-ego-0-2 (stored prompt", timeout=10_000)

        scene, plot = page.locator("canvas").nth(1), page.locator("canvas").nth(2)
        page.wait_for_timeout(1500)
        pose0, text0 = readout(page)
        scene0, plot0 = scene.screenshot(path=tmp_path / "a.png"), plot.screenshot(path=tmp_path / "p0.png")
        page.wait_for_timeout(1500)
        pose1, text1 = readout(page)
        scene.screenshot(path=tmp_path / "b.png")
        plot.screenshot(path=tmp_path / "p1.png")
        assert max(abs(a - b) for a, b in zip(pose0, pose1)) > 0.02, (text0, text1)  # the walk moves the pelvis
        for first, second in (("a.png", "b.png"), ("p0.png", "p1.png")):  # frames drawn by the browser differ
            diff = ImageChops.difference(Image.open(tmp_path / first).convert("RGB"),
                                         Image.open(tmp_path / second).convert("RGB"))
            assert diff.getbbox() is not None, f"{first} and {second} are the same picture"
        assert scene0 and plot0

        pick(page, "Clip", os.path.join("clips", "broken.npz"))
        page.get_by_role("button", name="Track clip").click()
        expect(para(page, "Not changed:")).to_contain_text("broken.npz: not a valid clip archive",
                                                                 timeout=10_000)
        expect(para(page, "z from:")).to_contain_text("reward move-ego-0-2")
        field(page, "Items").fill("move-ego-0-2:2,no-such-task:2")
        page.get_by_role("button", name="Play timeline").click()
        expect(para(page, "Not changed:")).to_contain_text("no-such-task", timeout=10_000)
        expect(para(page, "z from:")).to_contain_text("reward move-ego-0-2")
        pose2, _ = readout(page)
        page.wait_for_timeout(700)
        assert readout(page)[0] != pose2  # the body keeps running under the walk prompt

        shot = Path(os.environ.get("FBCPR_PLAY_SCREENSHOT", tmp_path / "play.png"))
        page.get_by_role("button", name="Reset standing").click()
        page.get_by_role("button", name="Prompt reward").click()  # a good prompt clears the message
        expect(para(page, "Not changed:")).to_have_count(0, timeout=10_000)
        para(page, "z from:").scroll_into_view_if_needed()
        close = page.locator(".mantine-Notification-closeButton")  # the note that WebGL runs in software
        if close.count():
            close.first.click()
        page.wait_for_timeout(1500)
        page.screenshot(path=shot)
        browser.close()
    assert Image.open(shot).size == (960, 600)
