"""three.js (npm `three`, GLTFLoader + AnimationMixer) playing a GLB in headless Chromium, driven by npm
`playwright-core` from node: what a web page shows of drape's GLB, vertex by vertex.

Installed by the first call where missing: Debian `chromium` (apt-get) and the npm packages, pinned, into
build/node (git-ignored, shared with gltf_validator.py). Nothing is fetched at page run time: a node http
server on loopback serves three.js from build/node and the page maps `three` to it with an import map.

`run_node(script, *args)` runs any node ES module (with playwright-core importable and `launch()` from
`BROWSER_JS` pasted in by the caller) and returns the JSON it prints last: the viewer test drives its page
with it too.
"""

from __future__ import annotations

import base64
import json
import os
import shutil
import subprocess
import tempfile
from pathlib import Path

import numpy as np
from node_folder import NODE_DIR, installing

THREE_VERSION = "0.187.0"
PLAYWRIGHT_VERSION = "1.65.1"
CHROMIUM = Path("/usr/bin/chromium")
CHROMIUM_ARGS = ["--headless", "--no-sandbox", "--disable-gpu", "--disable-background-networking",
                 "--disable-component-update", "--no-first-run", "--enable-unsafe-swiftshader",
                 "--use-angle=swiftshader"]

# pasted at the top of every node script: launch() -> a playwright Browser on the system Chromium
BROWSER_JS = f"""
import {{ chromium }} from 'playwright-core';
const launch = () => chromium.launch({{executablePath: {json.dumps(str(CHROMIUM))}, headless: true,
  args: {json.dumps(CHROMIUM_ARGS)}}});
"""

PAGE_JS = BROWSER_JS + r"""
import http from 'node:http';
import fs from 'node:fs';
import path from 'node:path';

const [glbPath, specPath, outPath] = process.argv.slice(2);
const spec = JSON.parse(fs.readFileSync(specPath, 'utf8'));
const THREE_DIR = path.resolve('node_modules/three');

const PAGE = `<!doctype html><html><head><meta charset="utf-8"><link rel="icon" href="data:,">
<script type="importmap">{"imports": {"three": "/three/build/three.module.js",
  "three/addons/": "/three/examples/jsm/"}}</script></head><body>
<script type="module">
@@MODULE@@window.drapeReady = true;
</script></body></html>`;

const TYPES = {'.js': 'text/javascript', '.glb': 'model/gltf-binary', '.html': 'text/html'};
const server = http.createServer((req, res) => {
  const url = new URL(req.url, 'http://localhost');
  let file = null;
  if (url.pathname === '/') { res.writeHead(200, {'content-type': 'text/html'}); res.end(PAGE); return; }
  if (url.pathname === '/model.glb') file = glbPath;
  else if (url.pathname.startsWith('/three/')) {
    file = path.resolve(THREE_DIR, '.' + decodeURIComponent(url.pathname.slice(6)));
    if (!file.startsWith(THREE_DIR + path.sep)) file = null;
  }
  if (!file || !fs.existsSync(file)) { res.writeHead(404); res.end(); return; }
  res.writeHead(200, {'content-type': TYPES[path.extname(file)] || 'application/octet-stream'});
  fs.createReadStream(file).pipe(res);
});
await new Promise((ok) => server.listen(0, '127.0.0.1', ok));
const browser = await launch();
const problems = [];
try {
  const page = await browser.newPage();
  page.on('pageerror', (e) => problems.push('pageerror: ' + e.message));
  page.on('console', (m) => { if (m.type() === 'error') problems.push('console: ' + m.text()); });
  page.on('requestfailed', (r) => problems.push('requestfailed: ' + r.url()));
  await page.goto(`http://127.0.0.1:${server.address().port}/`);
  await page.waitForFunction(() => window.drapeReady === true, null, {timeout: 60000});
  const out = await page.evaluate(@@CALL@@, spec);
  out.problems = problems;
  fs.writeFileSync(outPath, JSON.stringify(out));
} finally {
  await browser.close();
  server.close();
}
"""


def page_js(module: str, call: str) -> str:
    """A node ES module (run_node's argv: the GLB's path, a spec JSON's path) serving a page on loopback whose
    module script is `module` (three.js importable as 'three' and 'three/addons/', the GLB at /model.glb; the
    page sets window.drapeReady when loaded), then writing what `call` (a JS function of the spec, run in the
    page) returns, as JSON with `problems` (the page's errors, console errors and failed requests)."""
    return PAGE_JS.replace("@@MODULE@@", module).replace("@@CALL@@", call)


PLAY_MODULE = r"""import * as THREE from 'three';
import { GLTFLoader } from 'three/addons/loaders/GLTFLoader.js';

function b64(f64) {
  const u8 = new Uint8Array(f64.buffer);
  let s = '';
  for (let i = 0; i < u8.length; i += 0x8000) s += String.fromCharCode.apply(null, u8.subarray(i, i + 0x8000));
  return btoa(s);
}

window.drapePlay = async (spec) => {
  const data = await (await fetch('/model.glb')).arrayBuffer();
  const gltf = await new GLTFLoader().parseAsync(data, '');
  const meshes = spec.meshes.map((name) => {
    let found = null;
    gltf.scene.traverse((o) => { if (o.isMesh && o.name === name) found = o; });
    if (!found) throw new Error('no mesh named ' + name);
    return found;
  });
  const mixer = new THREE.AnimationMixer(gltf.scene);
  const action = mixer.clipAction(gltf.animations[0]);
  action.setLoop(THREE.LoopOnce);  // the last key is the last frame, not frame 0 again
  action.clampWhenFinished = true;
  const out = {revision: THREE.REVISION, skinned: meshes.map((m) => m.isSkinnedMesh === true),
               duration: gltf.animations[0].duration, positions: {}};
  const v = new THREE.Vector3();
  for (const name of spec.meshes) out.positions[name] = [];
  for (const time of spec.times) {
    action.reset();
    action.play();
    mixer.setTime(time);
    gltf.scene.updateMatrixWorld(true);
    meshes.forEach((mesh, k) => {
      const n = mesh.geometry.attributes.position.count;
      const p = new Float64Array(3 * n);
      for (let i = 0; i < n; i++) {
        mesh.getVertexPosition(i, v);  // morphed, then skinned (SkinnedMesh), in the mesh's space
        v.applyMatrix4(mesh.matrixWorld);
        p[3 * i] = v.x; p[3 * i + 1] = v.y; p[3 * i + 2] = v.z;
      }
      out.positions[spec.meshes[k]].push(b64(p));
    });
  }
  return out;
};
"""
PLAYER_JS = page_js(PLAY_MODULE, "(s) => window.drapePlay(s)")


def _installed_version(package: str) -> str | None:
    meta = NODE_DIR / "node_modules" / package / "package.json"
    return json.loads(meta.read_text())["version"] if meta.exists() else None


def ensure_browser() -> Path:
    """Chromium, node, three and playwright-core, installed where missing -> the node folder (scripts run there)."""
    wanted = {"three": THREE_VERSION, "playwright-core": PLAYWRIGHT_VERSION}
    if CHROMIUM.exists() and all(_installed_version(p) == v for p, v in wanted.items()):
        return NODE_DIR
    with installing():
        if not CHROMIUM.exists():
            env = {**os.environ, "DEBIAN_FRONTEND": "noninteractive"}
            install = ["apt-get", "install", "-y", "-q", "--no-install-recommends", "chromium"]
            if subprocess.run(install, env=env, capture_output=True).returncode != 0:
                subprocess.run(["apt-get", "update", "-q"], env=env, check=True, capture_output=True, timeout=600)
                subprocess.run(install, env=env, check=True, capture_output=True, timeout=1200)
        if not shutil.which("node") or not shutil.which("npm"):
            raise RuntimeError("three.js in Chromium needs node and npm (Debian: apt-get install nodejs npm)")
        missing = [f"{p}@{v}" for p, v in wanted.items() if _installed_version(p) != v]
        if missing:
            subprocess.run(["npm", "install", "--silent", "--no-audit", "--no-fund", "--save-exact", "--prefix",
                            str(NODE_DIR), *missing], check=True, timeout=600)
    return NODE_DIR


def run_node(script: str, *args: str, timeout: float = 300) -> dict:
    """Run a node ES module (source text) in build/node with `args`; it writes its answer as JSON to the
    path given as its last argument -> that answer."""
    node_dir = ensure_browser()
    with tempfile.TemporaryDirectory(dir=node_dir, prefix="run-") as tmp:
        path, out = Path(tmp) / "script.mjs", Path(tmp) / "out.json"
        path.write_text(script)
        done = subprocess.run(["node", str(path), *args, str(out)], capture_output=True, text=True,
                              timeout=timeout, cwd=node_dir)
        if done.returncode != 0 or not out.exists():
            raise RuntimeError(f"node failed ({done.returncode}): {done.stderr[-3000:]}{done.stdout[-1000:]}")
        return json.loads(out.read_text())


def threejs_play(glb: bytes, mesh_names: list[str], frames: list[int], fps: float) -> dict[str, dict[int, np.ndarray]]:
    """The GLB loaded by three.js's GLTFLoader in headless Chromium (one launch), its first animation set by an
    AnimationMixer to time frame / fps -> {mesh name: {frame: world positions (N, 3) float64}}, every vertex
    morphed and skinned by three's SkinnedMesh.getVertexPosition. Raises on any page error."""
    with tempfile.TemporaryDirectory() as tmp:
        glb_path, spec_path = Path(tmp) / "model.glb", Path(tmp) / "spec.json"
        glb_path.write_bytes(glb)
        spec_path.write_text(json.dumps({"meshes": list(mesh_names), "times": [f / fps for f in frames]}))
        out = run_node(PLAYER_JS, str(glb_path), str(spec_path))
    if out["problems"]:
        raise RuntimeError(f"the page reported: {out['problems'][:10]}")
    if out["revision"] != THREE_VERSION.split(".")[1]:
        raise RuntimeError(f"three.js r{out['revision']} played, not {THREE_VERSION}")
    return {name: {f: np.frombuffer(base64.b64decode(b), dtype="<f8").reshape(-1, 3)
                   for f, b in zip(frames, out["positions"][name], strict=True)}
            for name in mesh_names}


def threejs_positions(glb: bytes, mesh_name: str, frames: list[int], fps: float) -> dict[int, np.ndarray]:
    """One mesh of threejs_play: {frame: world positions (N, 3)}."""
    return threejs_play(glb, [mesh_name], frames, fps)[mesh_name]
