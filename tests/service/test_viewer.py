"""GET /viewer/: the page, its vendored three.js, the generated outfits it offers, and the page itself driven
in headless Chromium against a live server (playwright-core from node, tests/schemas/threejs_player.py):
pick an outfit and a clip, Play, a frame renders, the slider moves, no console error, nothing loaded from
outside the service; then two garments worn together (the layers tab: a combination of GET /v1/layers), then a
garment template from one keyframe (a sampled design of the intrinsic space), then an uploaded mocap file
(BVH) through the keyframe group, the layers group and a generated outfit. The screenshots go to
build/viewer*.png on every run, and to docs/ where that is missing or with DRAPE_VIEWER_SCREENSHOT=1 (renders
differ in their bytes from run to run, so a plain test run leaves the committed ones alone)."""

import os
import re
import shutil
import sys
from pathlib import Path

import numpy as np
import pytest

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "schemas"))
from svc_env import live_server  # noqa: E402
from threejs_player import BROWSER_JS, THREE_VERSION, run_node  # noqa: E402

from drape.service.routers.viewer import OUTFIT_TYPES, STATIC  # noqa: E402

ROOT = Path(__file__).resolve().parents[2]
SCREENSHOT, DOCS_SCREENSHOT = ROOT / "build" / "viewer.png", ROOT / "docs" / "viewer.png"
CLIP = "kick"  # 47 frames: frames x ~2,500 vertices within the test service's 300,000 posed values

DRIVE_JS = BROWSER_JS + r"""
import fs from 'node:fs';
const [base, shot, bvh, outPath] = process.argv.slice(2);
const origin = new URL(base).origin;
const out = {problems: [], external: [], frames: []};
const browser = await launch();
// Play, wait until `flag` of the viewer's state is set and frames render, then the slider at 4 moments, the
// state, the status and a screenshot (suffix `name`).
async function playWatched(page, flag, name) {
  await page.click('#play');
  await page.waitForFunction((f) => (window.drapeViewer[f] && window.drapeViewer.playing
                                     && window.drapeViewer.framesRendered >= 3) || window.drapeViewer.error,
                             flag, {timeout: 180000});
  const frames = [];
  for (let i = 0; i < 4; i++) { frames.push(Number(await page.inputValue('#frame'))); await page.waitForTimeout(400); }
  const seen = {state: await page.evaluate(() => ({...window.drapeViewer})), frames,
                status: await page.textContent('#status')};
  await page.screenshot({path: shot.replace(/\.png$/, `_${name}.png`)});
  return seen;
}
try {
  const page = await browser.newPage({viewport: {width: 1000, height: 700}});
  page.on('console', (m) => { if (m.type() === 'error') out.problems.push('console: ' + m.text()); });
  page.on('pageerror', (e) => out.problems.push('pageerror: ' + e.message));
  page.on('response', (r) => { if (r.status() >= 400) out.problems.push(`${r.status()} ${r.url()}`); });
  await page.route('**/*', (route) => {
    const url = route.request().url();
    if (url.startsWith(origin + '/') || url.startsWith('data:')) return route.continue();
    out.external.push(url);
    return route.abort();
  });
  await page.goto(base + '/viewer');
  out.url = page.url();
  await page.waitForFunction(() => window.drapeViewer && (window.drapeViewer.ready || window.drapeViewer.error),
                             null, {timeout: 60000});
  out.webgl = await page.evaluate(() => window.drapeViewer.webgl);
  out.clips = await page.$$eval('#clip option', (os) => os.map((o) => o.value));
  out.bodies = await page.$$eval('#body option', (os) => os.map((o) => o.value));
  await page.selectOption('#outfit', 'dress');
  await page.selectOption('#clip', 'CLIP');
  await page.click('#play');
  await page.waitForFunction(() => (window.drapeViewer.loaded && window.drapeViewer.framesRendered >= 3)
                             || window.drapeViewer.error, null, {timeout: 180000});
  for (let i = 0; i < 6; i++) {  // the slider follows the playing animation
    out.frames.push(Number(await page.inputValue('#frame')));
    await page.waitForTimeout(400);
  }
  // pause on frame 20 through the slider, then the screenshot
  await page.$eval('#frame', (s) => { s.value = '20'; s.dispatchEvent(new Event('input', {bubbles: true})); });
  const rendered = await page.evaluate(() => window.drapeViewer.framesRendered);
  await page.waitForFunction((n) => window.drapeViewer.framesRendered >= n + 3, rendered, {timeout: 60000});
  out.state = await page.evaluate(() => ({...window.drapeViewer}));
  out.status = await page.textContent('#status');
  await page.screenshot({path: shot});
  // two garments worn together: the first combination of GET /v1/layers, with its thickness input
  out.layerOptions = await page.$$eval('#outfit optgroup option', (os) => os.map((o) => o.value)
    .filter((v) => v.startsWith('layers:')));
  await page.selectOption('#outfit', out.layerOptions[0]);
  out.thickness = {shown: await page.isVisible('#thickness'), min: await page.getAttribute('#thickness', 'min'),
                   max: await page.getAttribute('#thickness', 'max')};
  out.layers = await playWatched(page, 'layers', 'layers');
  // a garment template from one keyframe: a sampled design of the intrinsic space (GET /v1/garments)
  out.templateOptions = await page.$$eval('#outfit optgroup option', (os) => os.map((o) => o.value)
    .filter((v) => v.startsWith('intrinsic:')));
  await page.selectOption('#outfit', out.templateOptions[0]);
  out.design = {shown: await page.isVisible('#design'), bodyDisabled: await page.isDisabled('#body')};
  await page.fill('#design', '3');
  out.keyframed = await playWatched(page, 'keyframed', 'intrinsic');
  // an uploaded mocap file (the routes' multipart motion_file): the keyframed garment, the layers, a generated outfit
  out.uploads = [];
  await page.selectOption('#clip', 'file');
  out.fileShown = await page.isVisible('#motionFile');
  await page.setInputFiles('#motionFile', bvh);
  for (const outfit of [out.templateOptions[0], out.layerOptions[0], 'tshirt']) {
    await page.selectOption('#outfit', outfit);
    await page.evaluate(() => { window.drapeViewer.loaded = false; });
    await page.click('#play');
    await page.waitForFunction(() => (window.drapeViewer.loaded && window.drapeViewer.framesRendered >= 3)
                               || window.drapeViewer.error, null, {timeout: 180000});
    out.uploads.push({outfit, state: await page.evaluate(() => ({...window.drapeViewer})),
                      status: await page.textContent('#status')});
  }
} finally {
  await browser.close();
}
fs.writeFileSync(outPath, JSON.stringify(out));
""".replace("'CLIP'", repr(CLIP))


KEY_JS = BROWSER_JS + r"""
import fs from 'node:fs';
const [base, outPath] = process.argv.slice(2);
const out = {problems: []};
const browser = await launch();
try {
  const page = await browser.newPage();
  page.on('console', (m) => { if (m.type() === 'error') out.problems.push('console: ' + m.text()); });
  page.on('pageerror', (e) => out.problems.push('pageerror: ' + e.message));
  page.on('response', (r) => { if (r.status() >= 400) out.problems.push(`${r.status()} ${new URL(r.url()).pathname}`); });
  await page.goto(base + '/viewer');
  await page.waitForFunction(() => window.drapeViewer && window.drapeViewer.error, null, {timeout: 60000});
  out.before = {status: await page.textContent('#status'), ready: await page.evaluate(() => window.drapeViewer.ready),
                problems: out.problems.splice(0)};
  await page.fill('#key', 's3cret');
  await page.press('#key', 'Tab');  // change: the catalogue again, with the key
  await page.waitForFunction(() => window.drapeViewer.ready, null, {timeout: 60000});
  out.clips = await page.$$eval('#clip option', (os) => os.length);
} finally {
  await browser.close();
}
fs.writeFileSync(outPath, JSON.stringify(out));
"""


ONE_FRAME_JS = BROWSER_JS + r"""
import fs from 'node:fs';
const [base, bvh, outPath] = process.argv.slice(2);
const out = {problems: [], plays: []};
const browser = await launch();
try {
  const page = await browser.newPage({viewport: {width: 800, height: 600}});
  page.on('console', (m) => { if (m.type() === 'error') out.problems.push('console: ' + m.text()); });
  page.on('pageerror', (e) => out.problems.push('pageerror: ' + e.message));
  await page.goto(base + '/viewer/');
  await page.waitForFunction(() => window.drapeViewer && (window.drapeViewer.ready || window.drapeViewer.error),
                             null, {timeout: 60000});
  const values = await page.$$eval('#outfit option', (os) => os.map((o) => o.value));
  await page.selectOption('#clip', 'file');
  await page.setInputFiles('#motionFile', bvh);
  for (const outfit of [values.find((v) => v.startsWith('intrinsic:')), values.find((v) => v.startsWith('layers:')),
                        'tshirt']) {
    await page.selectOption('#outfit', outfit);
    await page.evaluate(() => { window.drapeViewer.loaded = false; });
    await page.click('#play');
    await page.waitForFunction(() => (window.drapeViewer.loaded && window.drapeViewer.framesRendered >= 3)
                               || window.drapeViewer.error, null, {timeout: 180000});
    await page.waitForTimeout(300);  // more frames drawn: the one frame must stay put
    out.plays.push({outfit, state: await page.evaluate(() => ({...window.drapeViewer})),
                    label: await page.textContent('#frameLabel'), status: await page.textContent('#status'),
                    sliderDisabled: await page.isDisabled('#frame')});
  }
} finally {
  await browser.close();
}
fs.writeFileSync(outPath, JSON.stringify(out));
"""

def test_the_viewer_files(http):
    r = http.get("/viewer", follow_redirects=False)
    assert r.status_code == 308 and r.headers["location"] == "viewer/"
    page = http.get("/viewer/")
    assert page.status_code == 200 and page.headers["content-type"].startswith("text/html")
    assert re.findall(r'<option value="(\w+)">generated', page.text) == list(OUTFIT_TYPES)
    js = http.get("/viewer/viewer.js")
    assert js.status_code == 200 and js.headers["content-type"].startswith("text/javascript")
    three = http.get("/viewer/three/three.module.js")
    assert three.status_code == 200 and "three.core.js" in three.text
    assert f"REVISION = '{THREE_VERSION.split('.')[1]}'" in http.get("/viewer/three/three.core.js").text
    assert "MIT License" in http.get("/viewer/three/LICENSE").text
    for path in ("/viewer/nothing.js", "/viewer/../app.py", "/viewer/%2e%2e/app.py", "/viewer/three/../../app.py"):
        assert http.get(path).status_code == 404, path
    assert not [p for p in http.get("/openapi.json").json()["paths"] if p.startswith("/viewer")]
    # every address the page's own files name is relative (nothing from a CDN)
    for name in ("index.html", "viewer.js"):
        text = (STATIC / name).read_text()
        assert not re.search(r"""(src|href|from|import)\s*=?\s*["'](https?:)?//""", text), name


@pytest.mark.parametrize("kind", OUTFIT_TYPES)
def test_the_generated_outfits(http, kind):
    r = http.get(f"/viewer/outfits/{kind}.obj")
    assert r.status_code == 200 and r.headers["content-type"].startswith("model/obj")
    v = np.array([line.split()[1:] for line in r.text.splitlines() if line.startswith("v ")], float)
    f = np.array([line.split()[1:] for line in r.text.splitlines() if line.startswith("f ")], int)
    assert 2000 <= len(v) <= 3000 and f.min() == 1 and f.max() == len(v)
    rig = http.post("/v1/outfits/rig", files={"mesh": (f"{kind}.obj", r.content)}, headers={"accept": "application/x-npz"})
    assert rig.status_code == 200, rig.text[:300]


def test_an_unknown_outfit_is_a_404_problem(http):
    r = http.get("/viewer/outfits/cape.obj")
    assert r.status_code == 404 and r.headers["content-type"] == "application/problem+json"
    assert "tshirt" in r.json()["detail"]


def test_the_page_plays_an_outfit_in_chromium(server_url, tmp_path):
    from tests.cmu_bvh import cmu_bvh

    SCREENSHOT.parent.mkdir(exist_ok=True)
    SCREENSHOT.unlink(missing_ok=True)
    bvh = tmp_path / "jump_120fps.bvh"
    bvh.write_bytes(cmu_bvh(frames=120, fps=120.0))  # 1 s: 30 frames once imported at the routes' 30 fps
    out = run_node(DRIVE_JS, server_url, str(SCREENSHOT), str(bvh), timeout=500)
    print(f"\nWebGL {out['webgl']}; slider {out['frames']}; status {out['status']!r}")
    assert out["url"].endswith("/viewer/")
    assert out["problems"] == [] and out["external"] == []
    assert out["webgl"] and "WebGL" in out["webgl"]
    assert CLIP in out["clips"] and "neutral" in out["bodies"]
    state = out["state"]
    assert state["error"] is None and state["loaded"] and state["frames"] == 47
    assert len(set(out["frames"])) >= 3, out["frames"]  # the slider moved while playing
    assert state["frame"] == 20 and not state["playing"]  # the slider set the frame and paused
    assert SCREENSHOT.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    if not DOCS_SCREENSHOT.exists() or os.environ.get("DRAPE_VIEWER_SCREENSHOT") == "1":
        shutil.copyfile(SCREENSHOT, DOCS_SCREENSHOT)
    # the layers tab: the combinations of GET /v1/layers, played from POST /v1/layers/animate's GLB
    assert out["layerOptions"] == ["layers:tshirt:jacket", "layers:tanktop:longsleeve"]
    assert out["thickness"]["shown"] and float(out["thickness"]["min"]) < float(out["thickness"]["max"])
    layers = out["layers"]
    assert layers["state"]["error"] is None and layers["state"]["frames"] == 47
    assert layers["state"]["layers"]["inner"] == "tshirt" and layers["state"]["layers"]["thickness"] == 0.006
    assert "tshirt under jacket" in layers["status"] and len(set(layers["frames"])) >= 2, layers["frames"]
    shot = SCREENSHOT.with_name("viewer_layers.png")
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    if not DOCS_SCREENSHOT.with_name("viewer_layers.png").exists() or os.environ.get("DRAPE_VIEWER_SCREENSHOT") == "1":
        shutil.copyfile(shot, DOCS_SCREENSHOT.with_name("viewer_layers.png"))
    # the keyframe tab: each intrinsic template of GET /v1/garments, a sampled design played from
    # POST /v1/garments/{name}/animate's GLB
    import httpx

    intrinsic = [g["name"] for g in httpx.get(f"{server_url}/v1/garments").json()["garments"]
                 if "intrinsic" in g["models"]]
    assert out["templateOptions"] == [f"intrinsic:{name}" for name in intrinsic] and intrinsic
    assert out["design"] == {"shown": True, "bodyDisabled": True}
    keyframed = out["keyframed"]
    assert keyframed["state"]["error"] is None and keyframed["state"]["frames"] == 47
    assert keyframed["state"]["layers"] is None
    assert keyframed["state"]["keyframed"]["garment"] == intrinsic[0] and keyframed["state"]["keyframed"]["design"] == 3
    assert f"{intrinsic[0]} (intrinsic" in keyframed["status"] and len(set(keyframed["frames"])) >= 2, keyframed["frames"]
    shot = SCREENSHOT.with_name("viewer_intrinsic.png")
    assert shot.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n"
    if not DOCS_SCREENSHOT.with_name("viewer_intrinsic.png").exists() or os.environ.get("DRAPE_VIEWER_SCREENSHOT") == "1":
        shutil.copyfile(shot, DOCS_SCREENSHOT.with_name("viewer_intrinsic.png"))
    # an uploaded BVH drives both the keyframed garment and a rigged outfit
    assert out["fileShown"]
    assert [u["outfit"] for u in out["uploads"]] == [f"intrinsic:{intrinsic[0]}", out["layerOptions"][0], "tshirt"]
    for u in out["uploads"]:
        assert u["state"]["error"] is None and u["state"]["loaded"] and u["state"]["frames"] == 30, u
        assert "jump_120fps.bvh: 30 frames" in u["status"], u["status"]


def test_the_page_shows_a_one_frame_motion(server_url, tmp_path):
    """A mocap file of one frame (a single pose) is a valid motion: the routes answer a GLB of one frame (the
    vertex animations with no animation at all, the skinned one a clip of duration 0), and the page shows it at
    frame 0 of 0 through the keyframe group, the layers group and a generated outfit, without an error."""
    from tests.cmu_bvh import cmu_bvh

    bvh = tmp_path / "pose.bvh"
    bvh.write_bytes(cmu_bvh(frames=1, fps=30.0))
    out = run_node(ONE_FRAME_JS, server_url, str(bvh), timeout=500)
    assert out["problems"] == []
    assert [p["outfit"].split(":")[0] for p in out["plays"]] == ["intrinsic", "layers", "tshirt"]
    for p in out["plays"]:
        assert p["state"]["error"] is None and p["state"]["loaded"], p
        assert p["state"]["frames"] == 1 and p["state"]["frame"] == 0 and p["label"] == "0 / 0", p
        assert p["sliderDisabled"] and "pose.bvh: 1 frames" in p["status"], p

def test_the_page_asks_for_the_api_key_when_the_service_has_one(settings):
    """The page itself needs no key; the catalogue answers 401 until the key is typed into the page."""
    with live_server(settings.model_copy(update={"api_key": "s3cret"})) as url:
        out = run_node(KEY_JS, url, timeout=300)
    assert not out["before"]["ready"] and "401" in out["before"]["status"]
    assert "API key" in out["before"]["status"]
    assert {p for p in out["before"]["problems"] if not p.startswith("console: Failed to load resource")} == {
        "401 /v1/bodies", "401 /v1/motions", "401 /v1/layers", "401 /v1/garments"}
    assert out["problems"] == [] and out["clips"] >= 15
