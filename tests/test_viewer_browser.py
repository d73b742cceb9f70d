"""hevr.Viewer as a person uses it: JupyterLab in a real headless browser, dragging on the frame.

The test starts a JupyterLab server on 127.0.0.1 (a free port, a token, a temporary root and
Jupyter dirs, a kernel spec of this interpreter) with a notebook that opens a tiny encrypted
store with a pyramid level (24³ phantom, 256-bit key, 96² frames) in a ``hevr.Viewer`` and
writes, each time a frame is shown, the sliders, the camera, the request, the decrypted frame
and a digest of the PNG to files. Debian's Chromium (``/usr/bin/chromium``) driven by its ``/usr/bin/chromedriver``
(an explicit Selenium ``Service``: Selenium Manager downloads nothing) opens the notebook, runs
it from JupyterLab's *Run* menu, then

* drags on the frame with real pointer actions (press, a burst of moves, release): previews at
  the pyramid level arrive while the button is down, fewer messages go to the kernel than there
  were pointer moves (coalesced while a render is in flight), and the release brings the full
  frame of the final position — the sliders in the kernel *and their readouts in the page* at
  30° − 180° × Δx / width and 20° + 180° × Δy / height, on their 1° steps;
* turns the wheel over the frame: the view angle shrinks by 2^(Δy/500), a preview, then the full
  frame once the viewer's ``settle`` time has passed;

and checks that every frame arrived (the ``<img>``'s frame counter) and is right: the decrypted
frame the kernel wrote is compared with :func:`hevr.render_plain` within
:func:`hevr.error_bound` here, and the PNG the page shows is byte for byte the kernel's.

A screenshot after the drag goes to the test's temporary folder, or to ``$HEVR_SCREENSHOT``
when set (how ``docs/viewer-drag.png`` is made). Without Chromium the test is skipped with the
reason, except under CI (``$CI`` set), where it fails: ``.ci/run`` installs it. About 15 s on
this project's 2-core machine (half of it JupyterLab and the browser starting).
"""

from __future__ import annotations

import base64
import contextlib
import hashlib
import importlib.util
import json
import logging
import os
import secrets
import socket
import subprocess
import sys
import time
import urllib.request
import warnings
from pathlib import Path

import numpy as np
import pytest

import hevr

pytestmark = pytest.mark.slow
log = logging.getLogger(__name__)

CHROMIUM = Path("/usr/bin/chromium")
CHROMEDRIVER = Path("/usr/bin/chromedriver")
SIZE = 96  # frame pixels per axis; the page shows it at 256 CSS pixels
MOVES = (12, 10, -4)  # pointer moves of (dx, dy) CSS pixels in the drag
WHEEL = -250  # wheel deltaY in CSS pixels: towards the volume


def _need(ok: bool, reason: str) -> None:
    """Skip where the browser cannot be had; under CI, fail (.ci/run installs everything)."""
    if not ok:
        if os.environ.get("CI"):
            pytest.fail(f"{reason} (CI installs it: .ci/run)")
        pytest.skip(reason)


NOTEBOOK_CELLS = [
    """import hashlib, json, warnings
import numpy as np
import hevr
warnings.simplefilter("ignore", hevr.InsecureKeyWarning)
ev = OPEN
priv = hevr.load_key("key.json")
vol = np.load("vol.npy")""",
    f'''viewer = hevr.Viewer(ev, priv, volume=vol, width={SIZE}, height={SIZE}, mode="tf", settle=0.5)

def record(change):
    """Each frame shown: the decrypted frame and what it is, for the test to check."""
    e = viewer.history[-1]
    n = len(viewer.history)
    np.save(f"frame-{{n}}.npy", viewer.frame.image)
    line = dict(n=n, level=e["level"], camera=e["camera"], request=e["request"], error=e["error"],
                bound=e["bound"], sliders=[viewer.azimuth.value, viewer.elevation.value, viewer.view_angle.value],
                png=hashlib.sha256(bytes(change["new"])).hexdigest(), messages=viewer.orbit.messages)
    with open("frames.jsonl", "a") as f:
        f.write(json.dumps(line) + "\\n")

viewer.image.observe(record, names="value")
viewer''',
]


def _importable(name: str) -> bool:
    return importlib.util.find_spec(name) is not None


def _free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return s.getsockname()[1]


@pytest.fixture(scope="module", params=["local", "remote"])
def lab(request, tmp_path_factory, keypair256):
    """A JupyterLab server on 127.0.0.1 with the notebook and the store in its root: (url, root, ev, vol).
    ``remote``: the notebook opens the store through a real ``hevr serve`` (hevr.connect), as a key
    holder whose kernel never joins the server's cluster."""
    nbformat = pytest.importorskip("nbformat")
    _need(_importable("jupyterlab"), "JupyterLab is not installed (pip install 'hevr[test]')")
    _pub, priv = keypair256
    base = tmp_path_factory.mktemp("lab")
    root = base / "root"
    root.mkdir()
    vol = hevr.phantom(24)
    ev = hevr.encrypt_volume(vol, root / "v.zarr", priv, brick=8, vector_dims=3, progress=False)
    ev = hevr.build_pyramid(ev, 1, progress=False)
    np.save(root / "vol.npy", vol)
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", hevr.InsecureKeyWarning)
        priv.save(root / "key.json")
    nb = nbformat.v4.new_notebook()
    nb.metadata["kernelspec"] = {"name": "hevr-test", "display_name": "hevr test", "language": "python"}
    served = contextlib.ExitStack()
    if request.param == "remote":
        from _serving import hevr_serve

        server_url, _, _ = served.enter_context(hevr_serve(str(root / "v.zarr")))
        opener = f"hevr.connect({server_url!r}).open({ev.meta.store_id!r})"
    else:
        opener = 'hevr.open_volume("v.zarr")'
    nb.cells = [nbformat.v4.new_code_cell(src.replace("OPEN", opener)) for src in NOTEBOOK_CELLS]
    nb.cells[1].metadata["jupyter"] = {"source_hidden": True}  # folded: the viewer shows in the screenshot
    nbformat.write(nb, root / "drag.ipynb")
    env = dict(os.environ)
    for name in ("config", "data", "runtime"):
        (base / name).mkdir()
        env[f"JUPYTER_{name.upper()}_DIR"] = str(base / name)
    news = base / "config" / "lab" / "user-settings" / "@jupyterlab" / "apputils-extension"
    news.mkdir(parents=True)  # no "get notified about Jupyter news?" toast over the page
    (news / "notification.jupyterlab-settings").write_text('{"fetchNews": "false"}')
    spec = base / "data" / "kernels" / "hevr-test"
    spec.mkdir(parents=True)
    (spec / "kernel.json").write_text(
        json.dumps(
            {
                "argv": [sys.executable, "-m", "ipykernel_launcher", "-f", "{connection_file}"],
                "display_name": "hevr test",
                "language": "python",
            }
        )
    )
    port, token = _free_port(), secrets.token_hex(16)
    server_log = open(base / "lab.log", "wb")  # noqa: SIM115 (closed below)
    proc = subprocess.Popen(
        [
            sys.executable,
            "-m",
            "jupyterlab",
            "--no-browser",
            "--ip=127.0.0.1",
            f"--port={port}",
            "--ServerApp.port_retries=0",
            f"--IdentityProvider.token={token}",
            f"--ServerApp.root_dir={root}",
            "--LabApp.check_for_updates_class=jupyterlab.NeverCheckForUpdate",
            *(["--allow-root"] if hasattr(os, "geteuid") and os.geteuid() == 0 else []),
        ],  # CI runs as root
        cwd=root,
        env=env,
        stdout=server_log,
        stderr=subprocess.STDOUT,
    )
    url = f"http://127.0.0.1:{port}"
    try:
        deadline = time.time() + 60
        while True:
            try:
                with urllib.request.urlopen(f"{url}/api/status?token={token}", timeout=2) as r:
                    if r.status == 200:
                        break
            except OSError:
                pass
            if proc.poll() is not None or time.time() > deadline:
                raise RuntimeError("JupyterLab did not start: " + (base / "lab.log").read_text()[-3000:])
            time.sleep(0.3)
        yield f"{url}/lab/tree/drag.ipynb?token={token}", root, ev, vol
    finally:
        proc.terminate()
        try:
            proc.wait(timeout=20)
        except subprocess.TimeoutExpired:
            proc.kill()
            proc.wait()
        server_log.close()
        served.close()


@pytest.fixture(scope="module")
def browser(tmp_path_factory):
    """Debian's headless Chromium through its chromedriver (nothing downloaded)."""
    _need(
        CHROMIUM.exists() and CHROMEDRIVER.exists(),
        "Debian's chromium and chromium-driver are not installed (apt-get install chromium chromium-driver)",
    )
    _need(_importable("selenium"), "selenium is not installed (pip install 'hevr[test]')")
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    opts = webdriver.ChromeOptions()
    opts.binary_location = str(CHROMIUM)
    for flag in (
        "--headless",
        "--no-sandbox",
        "--disable-gpu",
        "--disable-quic",
        "--no-first-run",
        "--disable-background-networking",
        "--disable-component-update",
        "--disable-sync",
        "--disable-dev-shm-usage",
        "--window-size=1200,720",
        f"--user-data-dir={tmp_path_factory.mktemp('chromium')}",
    ):
        opts.add_argument(flag)
    driver = webdriver.Chrome(service=Service(executable_path=str(CHROMEDRIVER)), options=opts)
    try:
        yield driver
    finally:
        driver.quit()


def _frames(root: Path) -> list[dict]:
    """The frames the kernel recorded so far (whole lines only: the kernel may be writing one)."""
    path = root / "frames.jsonl"
    return [json.loads(line) for line in path.read_text().split("\n")[:-1]] if path.exists() else []


def _wait(what: str, fn, timeout: float = 30.0, every: float = 0.1):
    deadline = time.time() + timeout
    while True:
        value = fn()
        if value:
            return value
        if time.time() > deadline:
            raise AssertionError(f"timed out waiting for {what}")
        time.sleep(every)


def _shown_png(driver, img) -> bytes:
    """The bytes of the PNG the page shows (the <img>'s blob URL, fetched in the page)."""
    b64 = driver.execute_async_script(
        "const done = arguments[arguments.length - 1];"
        "fetch(arguments[0].src).then(r => r.arrayBuffer()).then(b => {"
        "  let s = ''; const u = new Uint8Array(b);"
        "  for (let i = 0; i < u.length; i++) s += String.fromCharCode(u[i]);"
        "  done(btoa(s)); }).catch(e => done('error: ' + e));",
        img,
    )
    assert not b64.startswith("error"), b64
    return base64.b64decode(b64)


def _right(root: Path, line: dict, ev, vol) -> None:
    """The frame the kernel decrypted is within error_bound of render_plain at its level."""
    cam = hevr.Camera.from_dict(line["camera"])
    level, kw = line["level"], line["request"]
    kw = {**kw, "nodes": [tuple(n) for n in kw["nodes"]]} if "nodes" in kw else kw
    frame = np.load(root / f"frame-{line['n']}.npy")
    ref = hevr.render_plain(vol, cam, value_range=ev.value_range, vector_dims=ev.vector_dims, level=level, **kw)
    bound = hevr.error_bound(ev, cam, level=level or None, **kw)
    assert frame.shape == ref.shape == (SIZE >> level, SIZE >> level, *ref.shape[2:])
    assert (np.abs(frame - ref) <= bound).all()
    assert line["error"] <= line["bound"]


def _readout(driver, name: str) -> str:
    """The readout text of the viewer's slider called ``name``, as the page shows it."""
    return driver.execute_script(
        "for (const s of document.querySelectorAll('.widget-slider')) {"
        "  const l = s.querySelector('.widget-label');"
        "  if (l && l.textContent.trim() === arguments[0]) {"
        "    const r = s.querySelector('.widget-readout'); return r.value ?? r.textContent; } }"
        "return null;",
        name,
    ).replace("\u2212", "-")  # d3-format writes a minus sign


def test_drag_and_wheel_in_jupyterlab(lab, browser, tmp_path):
    try:
        _drag_and_wheel(lab, browser, tmp_path)
    except BaseException:
        shot = tmp_path / "failure.png"
        browser.save_screenshot(str(shot))
        log.error("the page when the test failed: %s; the server's log: %s", shot, lab[1].parent / "lab.log")
        raise


def _drag_and_wheel(lab, browser, tmp_path) -> None:
    from selenium.webdriver.common.action_chains import ActionChains
    from selenium.webdriver.common.actions.wheel_input import ScrollOrigin
    from selenium.webdriver.common.by import By

    url, root, ev, vol = lab
    driver = browser
    t0 = time.time()
    driver.get(url)
    # the notebook is open and its kernel idle; then Run → Run All Cells, as a person would
    # focus the notebook (JupyterLab 4.6 may open it unfocused: then neither its status-bar items show
    # nor does Run All apply to it)
    from selenium.common.exceptions import WebDriverException

    def focus() -> bool:
        try:  # the cells re-render while the notebook loads: a stale one is clicked again
            driver.find_elements(By.CSS_SELECTOR, ".jp-NotebookPanel .jp-Cell")[0].click()
            return True
        except (IndexError, WebDriverException):
            return False

    _wait("the notebook", focus, timeout=120)
    _wait(
        "the notebook's kernel",
        lambda: driver.find_elements(  # the status bar: "hevr test | Idle"
            By.XPATH, "//*[contains(@class,'jp-StatusBar-TextItem') and normalize-space(.)='hevr test | Idle']"
        ),
        timeout=180,
    )  # a loaded 2-core machine starts the kernel slowly
    _wait(
        "the Run menu",
        lambda: driver.find_elements(By.XPATH, "//li[contains(@class,'lm-MenuBar-item')][normalize-space(.)='Run']"),
    )[0].click()
    _wait(
        "Run All Cells",
        lambda: driver.find_elements(By.CSS_SELECTOR, "li.lm-Menu-item[data-command='runmenu:run-all']"),
    )[0].click()
    _wait(
        "the file browser's tab",
        lambda: driver.find_elements(  # fold the file browser away
            By.CSS_SELECTOR, ".jp-SideBar li.lm-TabBar-tab[data-id='filebrowser']"
        ),
    )[0].click()
    img = _wait("the viewer's frame", lambda: driver.find_elements(By.CSS_SELECTOR, "img.hevr-drag"), timeout=90)[0]
    _wait("the first frame in the page", lambda: int(img.get_attribute("data-frames") or 0) >= 1)
    # the observer was attached after the first frame: that one is checked through the kernel's history
    assert _frames(root) == []
    assert img.size["width"] == 256 and _readout(driver, "azimuth") in ("30", "30.0")
    driver.execute_script("arguments[0].scrollIntoView({block: 'center'});", img)
    driver.execute_script(
        "window.__moves = 0; arguments[0].addEventListener('pointermove', () => { window.__moves += 1; });", img
    )

    # -- the drag: press, a burst of moves, release ------------------------------------------
    before = int(img.get_attribute("data-frames"))
    steps = MOVES[0]
    chain = ActionChains(driver, duration=0).move_to_element(img).click_and_hold()
    for _ in range(steps):
        chain.move_by_offset(MOVES[1], MOVES[2])
    chain.perform()
    previews = _wait("a preview during the drag", lambda: [f for f in _frames(root) if f["level"] == 1])
    ActionChains(driver, duration=0).release().perform()
    final = _wait("the full frame after the release", lambda: [f for f in _frames(root) if f["level"] == 0])
    assert len(final) == 1
    frames = _frames(root)
    full = frames[-1]
    assert full["level"] == 0 and all(f["level"] == 1 for f in frames[:-1]) and previews
    dx, dy = steps * MOVES[1], steps * MOVES[2]
    width, height = img.size["width"], img.size["height"]
    az, el = round(30.0 - 180.0 * dx / width), round(20.0 + 180.0 * dy / height)  # on the sliders' 1° steps
    assert full["sliders"][:2] == [az, el]  # every pointer move counted, once
    assert (
        full["camera"]
        == hevr.Camera.orbit(
            ev, azimuth=full["sliders"][0], elevation=full["sliders"][1], width=SIZE, height=SIZE
        ).to_dict()
    )  # the sliders' camera
    assert full["camera"]["width"] == SIZE and previews[0]["camera"]["width"] == SIZE // 2
    moves = driver.execute_script("return window.__moves;")
    sent = int(img.get_attribute("data-sent"))
    assert moves >= steps > sent == full["messages"]  # coalesced: fewer messages than moves with the button down
    for f in frames:
        _right(root, f, ev, vol)
    _wait("the frames in the page", lambda: int(img.get_attribute("data-frames")) == before + len(frames))
    assert hashlib.sha256(_shown_png(driver, img)).hexdigest() == full["png"]  # the page shows the kernel's frame
    _wait("the azimuth readout", lambda: _readout(driver, "azimuth") == f"{az:.0f}")
    assert _readout(driver, "elevation") == f"{el:.0f}"
    shot = Path(os.environ.get("HEVR_SCREENSHOT") or tmp_path / "viewer-drag.png")
    assert driver.save_screenshot(str(shot)) and shot.stat().st_size > 10_000

    # -- the wheel: a preview now, the full frame after `settle` ------------------------------
    n = len(frames)
    ActionChains(driver).scroll_from_origin(ScrollOrigin.from_element(img), 0, WHEEL).perform()
    zoomed = _wait("the full frame after the wheel", lambda: [f for f in _frames(root)[n:] if f["level"] == 0])[0]
    after = _frames(root)[n:]
    assert after[0]["level"] == 1 and after[-1] == zoomed
    assert zoomed["sliders"][2] == round(30.0 * 2 ** (WHEEL / 500.0))
    assert zoomed["sliders"][:2] == full["sliders"][:2]
    for f in after:
        _right(root, f, ev, vol)
    _wait("the last frame in the page", lambda: int(img.get_attribute("data-frames")) == before + n + len(after))
    assert hashlib.sha256(_shown_png(driver, img)).hexdigest() == zoomed["png"]
    log.info("browser test: %.1f s in the browser, %d messages for %d pointer moves", time.time() - t0, sent, moves)
