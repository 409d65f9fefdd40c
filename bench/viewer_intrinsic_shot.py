"""The viewer's keyframe tab on the shipped intrinsic skirt (docs/viewer_intrinsic.png): the service with its
default (embedded) models on a loopback port, the page driven in headless Chromium (the test suite's node +
playwright-core set-up, tests/schemas/threejs_player.py; installed where missing): pick the skirt, design 3,
the walk, Play, pause on frame 40, screenshot. tests/service/test_viewer.py drives the same tab against the test
service's random-init model, whose shapes are noise, so its screenshot stays under build/.
Run: .venv/bin/python -m bench.viewer_intrinsic_shot [OUT.png]  (about a minute on the 2-core machine)
"""

from __future__ import annotations

import sys
from pathlib import Path

from bench.http import loopback_server

sys.path.insert(0, str(Path(__file__).resolve().parents[1] / "tests" / "schemas"))
from threejs_player import BROWSER_JS, run_node  # noqa: E402

SHOT_JS = BROWSER_JS + r"""
import fs from 'node:fs';
const [base, shot, outPath] = process.argv.slice(2);
const out = {problems: []};
const browser = await launch();
try {
  const page = await browser.newPage({viewport: {width: 1000, height: 700}});
  page.on('console', (m) => { if (m.type() === 'error') out.problems.push('console: ' + m.text()); });
  page.on('pageerror', (e) => out.problems.push('pageerror: ' + e.message));
  await page.goto(base + '/viewer');
  await page.waitForFunction(() => window.drapeViewer && (window.drapeViewer.ready || window.drapeViewer.error),
                             null, {timeout: 60000});
  await page.selectOption('#outfit', 'intrinsic:skirt');
  await page.fill('#design', '3');
  await page.selectOption('#clip', 'walk');
  await page.click('#play');
  await page.waitForFunction(() => (window.drapeViewer.keyframed && window.drapeViewer.framesRendered >= 3)
                             || window.drapeViewer.error, null, {timeout: 180000});
  await page.$eval('#frame', (s) => { s.value = '40'; s.dispatchEvent(new Event('input', {bubbles: true})); });
  const rendered = await page.evaluate(() => window.drapeViewer.framesRendered);
  await page.waitForFunction((n) => window.drapeViewer.framesRendered >= n + 3, rendered, {timeout: 60000});
  out.state = await page.evaluate(() => ({...window.drapeViewer}));
  out.status = await page.textContent('#status');
  await page.screenshot({path: shot});
} finally {
  await browser.close();
}
fs.writeFileSync(outPath, JSON.stringify(out));
"""


def main(out: Path) -> None:
    with loopback_server() as url:
        answer = run_node(SHOT_JS, url, str(out.resolve()), timeout=400)
    if answer["problems"] or answer["state"]["error"]:
        sys.exit(f"the page failed: {answer['problems']} {answer['state']['error']}")
    print(f"{out}: {answer['status']}")


if __name__ == "__main__":
    main(Path(sys.argv[1]) if len(sys.argv) > 1 else Path("docs") / "viewer_intrinsic.png")
