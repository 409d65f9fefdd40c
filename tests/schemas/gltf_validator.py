"""The Khronos glTF validator (npm `gltf-validator`), run with node: installed into build/node by the
first call where missing (npm from the registry; nothing is fetched at run time by drape itself)."""

from __future__ import annotations

import json
import shutil
import subprocess
import tempfile
from pathlib import Path

from node_folder import NODE_DIR, installing

VERSION = "2.0.0-dev.3.10"
SCRIPT = """
import fs from 'fs';
import validator from 'gltf-validator';
const data = new Uint8Array(fs.readFileSync(process.argv[2]));
const report = await validator.validateBytes(data, {maxIssues: 0});
const issues = report.issues;
console.log(JSON.stringify({errors: issues.numErrors, warnings: issues.numWarnings,
  messages: issues.messages.filter(m => m.severity === 0).slice(0, 20)}));
"""


def ensure_validator() -> Path:
    """The validator's script, installed where missing (needs node and npm)."""
    if not shutil.which("node") or not shutil.which("npm"):
        raise RuntimeError("the glTF validator needs node and npm (Debian: apt-get install nodejs npm)")
    script = NODE_DIR / "validate.mjs"
    if (NODE_DIR / "node_modules" / "gltf-validator").exists() and script.exists() and script.read_text() == SCRIPT:
        return script
    with installing():
        if not (NODE_DIR / "node_modules" / "gltf-validator").exists():
            subprocess.run(["npm", "install", "--silent", "--no-audit", "--no-fund", "--prefix", str(NODE_DIR),
                            f"gltf-validator@{VERSION}"], check=True, timeout=600)
        if not script.exists() or script.read_text() != SCRIPT:
            script.write_text(SCRIPT)
    return script


def validate(glb: bytes) -> dict:
    """-> {"errors": int, "warnings": int, "messages": [the first 20 errors]} for the GLB bytes."""
    script = ensure_validator()
    with tempfile.NamedTemporaryFile(suffix=".glb") as f:
        f.write(glb)
        f.flush()
        out = subprocess.run(["node", str(script), f.name], capture_output=True, text=True, timeout=300,
                             cwd=NODE_DIR)
    if out.returncode != 0:
        raise RuntimeError(f"the validator failed: {out.stderr[-2000:]}")
    return json.loads(out.stdout)
