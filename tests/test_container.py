"""The container, without Docker: the Dockerfile's install, user, CMD and HEALTHCHECK reproduced here.

The slow test reads the Dockerfile and does what it says on this machine: copies what it COPYs into
a temporary WORKDIR, makes a clean venv, runs its `pip install` (non-editable, like the image), runs
its CMD as a non-root user with its ENV (host and port moved to 127.0.0.1 and a free port), waits for
/readyz, runs its HEALTHCHECK command, animates one outfit and stops the server with SIGTERM. The
fast tests keep the pieces it relies on honest (what [serve] holds, the CLI's message when a tool
package is missing, the build context).
"""

from __future__ import annotations

import io
import json
import os
import pwd
import shlex
import shutil
import signal
import socket
import subprocess
import sys
import tempfile
import time
import tomllib
from pathlib import Path

import httpx
import numpy as np
import pytest

ROOT = Path(__file__).resolve().parents[1]
# never in the image: torch (training), matplotlib (the [tools] extra), pymotion (a test reference)
NOT_SERVED = {"torch": "torch", "matplotlib": "matplotlib", "upc-pymotion": "pymotion"}
NON_ROOT = "nobody"


def dockerfile(path: Path = ROOT / "Dockerfile") -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) in order, continuation lines joined, comments dropped."""
    out: list[tuple[str, str]] = []
    pending = ""
    for raw in path.read_text().splitlines():
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        if line.endswith("\\"):
            pending += line[:-1].strip() + " "
            continue
        line = pending + line
        pending = ""
        word, _, rest = line.partition(" ")
        out.append((word.upper(), rest.strip()))
    assert not pending, "Dockerfile ends inside a continued line"
    return out


def only(instructions: list[tuple[str, str]], word: str) -> str:
    found = [a for w, a in instructions if w == word]
    assert found, f"the Dockerfile has no {word}"
    return found[-1]  # Docker keeps the last CMD / HEALTHCHECK / USER / WORKDIR


def env_of(instructions: list[tuple[str, str]]) -> dict[str, str]:
    env: dict[str, str] = {}
    for word, args in instructions:
        if word == "ENV":
            for item in shlex.split(args):
                key, eq, value = item.partition("=")
                assert eq, f"ENV {args!r}: only the KEY=VALUE form is read here"
                env[key] = value
    return env


def healthcheck(instructions: list[tuple[str, str]]) -> tuple[list[str], float]:
    """The HEALTHCHECK's command (shell form -> /bin/sh -c, as Docker runs it) and its --timeout in seconds."""
    args = only(instructions, "HEALTHCHECK")
    opts, sep, command = args.partition("CMD ")
    assert sep, f"HEALTHCHECK {args!r} has no CMD"
    timeout = 30.0  # Docker's default
    for opt in opts.split():
        if opt.startswith("--timeout="):
            value = opt.split("=", 1)[1]
            timeout = float(value[:-1]) * (60 if value.endswith("m") else 1)
    command = command.strip()
    argv = json.loads(command) if command.startswith("[") else ["/bin/sh", "-c", command]
    return argv, timeout


def pip_install_args(instructions: list[tuple[str, str]]) -> list[str]:
    """The arguments of the RUN's `pip install` (the part before/after && that is the install)."""
    for word, args in instructions:
        if word == "RUN":
            for part in args.split("&&"):
                tokens = shlex.split(part)
                if tokens[:2] == ["pip", "install"]:
                    return tokens[2:]
    raise AssertionError("the Dockerfile RUNs no `pip install`")


def copy_context(instructions: list[tuple[str, str]], workdir: Path) -> None:
    """Do the COPY instructions from this checkout into `workdir`, skipping .dockerignore's **/ names."""
    ignored = [line.strip().removeprefix("**/") for line in (ROOT / ".dockerignore").read_text().splitlines()
               if line.strip() and not line.startswith("#")]
    for word, args in instructions:
        if word != "COPY":
            continue
        *sources, dest = shlex.split(args)
        assert not any(s.startswith("--") for s in sources), f"COPY {args!r}: flags are not reproduced"
        target = workdir / dest
        for src in sources:
            here = ROOT / src
            into = target / src if (dest.endswith("/") or len(sources) > 1) else target
            if here.is_dir():
                shutil.copytree(here, into, ignore=shutil.ignore_patterns(*ignored))
            else:
                into.parent.mkdir(parents=True, exist_ok=True)
                shutil.copy2(here, into)


def free_port() -> int:
    with socket.socket() as s:
        s.bind(("127.0.0.1", 0))
        return int(s.getsockname()[1])


def run(cmd: list[str], **kw) -> subprocess.CompletedProcess[str]:
    return subprocess.run(cmd, capture_output=True, text=True, **kw)


# ---------------------------------------------------------------------------------------------------------------
# fast: the pieces the container relies on


def test_serve_extra_leaves_out_the_tools():
    extras = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["optional-dependencies"]
    serve = " ".join(extras["serve"]).lower()
    for dist in NOT_SERVED:
        assert dist not in serve, f"{dist} is in [serve]"
    tools = " ".join(extras["tools"]).lower()
    assert "matplotlib" in tools and "upc-pymotion" in " ".join(extras["dev"]).lower()
    assert any("tools" in d and d.startswith("drape[") for d in extras["dev"]), "[dev] must include [tools]"


def test_serving_path_imports_no_tool_package():
    code = ("import sys, drape.cli, drape.service.server, drape.service.app; drape.service.app.create_app();"
            f"bad = [m for m in sys.modules if m.split('.')[0] in {sorted(NOT_SERVED.values())!r}];"
            "print(bad); sys.exit(1 if bad else 0)")
    r = run([sys.executable, "-c", code])
    assert r.returncode == 0, r.stdout + r.stderr


@pytest.mark.parametrize(("module", "argv"), [
    ("matplotlib", ["render", "--body", "neutral", "--out", "x.png"]),
])
def test_cli_names_the_extra_when_a_tool_package_is_missing(monkeypatch, module, argv):
    from drape.cli import main

    monkeypatch.setitem(sys.modules, module, None)  # find_spec and import now see it as not installed
    with pytest.raises(SystemExit) as exc:
        main(argv)
    assert "pip install 'drape[tools]'" in str(exc.value.code)
    assert module in str(exc.value.code)


@pytest.mark.parametrize(("module", "extra", "importer", "argv"), [
    ("torch", "train", "drape.export.deepsd", ["export", "deepsd", "--init", "--out", "x"]),
    ("torch", "train", "drape.training.deepsd", ["train", "deepsd"]),
])
def test_cli_commands_that_import_a_training_package_name_its_extra(monkeypatch, capsys, module, extra, importer,
                                                                     argv):
    """`drape export deepsd --init` in `make serve`'s venv (no torch) ended in a ModuleNotFoundError traceback;
    every optional package the serving install lacks is one line naming the command and the extra, exit 1."""
    from drape.cli import main

    monkeypatch.setitem(sys.modules, module, None)
    monkeypatch.delitem(sys.modules, importer, raising=False)  # imported by an earlier test: import it again
    with pytest.raises(SystemExit) as exc:
        main(argv)
    err = capsys.readouterr().err
    assert exc.value.code == 1 and len(err.strip().splitlines()) == 1, err
    assert f"`drape {' '.join(argv[:2])}` needs {module}" in err and f"pip install 'drape[{extra}]'" in err, err


def test_dockerignore_keeps_local_state_out_of_the_context():
    ignored = {line.strip().rstrip("/") for line in (ROOT / ".dockerignore").read_text().splitlines()}
    assert {"data", "cache", "checkpoints", ".venv"} <= ignored


def test_dockerfile_is_readable_by_the_slow_test():
    steps = dockerfile()
    assert json.loads(only(steps, "CMD")) == ["drape", "serve"]
    argv, timeout = healthcheck(steps)
    assert argv[:2] == ["/bin/sh", "-c"] and "/healthz" in argv[2] and timeout == 5
    assert pip_install_args(steps) == [".[serve]"]
    assert only(steps, "USER") not in ("root", "0")
    assert {"DRAPE_HOST", "DRAPE_PORT"} <= env_of(steps).keys()


# ---------------------------------------------------------------------------------------------------------------
# slow: the image, reproduced


def _as_user() -> tuple[list[str], pwd.struct_passwd | None]:
    """The prefix that runs a command as a non-root user (the image's USER), or nothing when not root."""
    if os.geteuid() != 0:
        print(f"note: not root (uid {os.geteuid()}): the server runs as this user; the USER switch is not reproduced")
        return [], None
    user = pwd.getpwnam(NON_ROOT)
    return ["setpriv", f"--reuid={user.pw_uid}", f"--regid={user.pw_gid}", "--clear-groups"], user


def _python(as_user: list[str]) -> str:
    """This test's Python, or, where the non-root user cannot run it (pyenv under a 0700 /root), a
    system Python of the same minor version that it can."""
    minor = f"python{sys.version_info[0]}.{sys.version_info[1]}"
    candidates = [getattr(sys, "_base_executable", sys.executable)]
    candidates += [p for d in ("/usr/local/bin", "/usr/bin") if (p := shutil.which(minor, path=d))]
    probe = "import ensurepip, sys, venv; print(sys.version, sys.base_prefix)"
    for python in candidates:
        # the same interpreter for both users (a binary the user can start may still miss its own stdlib)
        theirs = run([*as_user, python, "-c", probe], cwd="/")
        if theirs.returncode == 0 and theirs.stdout == run([python, "-c", probe], cwd="/").stdout:
            return python
    pytest.fail(f"none of {candidates} runs as {NON_ROOT} with venv and ensurepip")


@pytest.mark.slow
@pytest.mark.timeout(1800)
def test_image_install_serves_as_non_root():
    steps = dockerfile()
    t_start = time.perf_counter()

    def stamp(what: str) -> None:
        print(f"{what}: {time.perf_counter() - t_start:.1f} s", flush=True)

    as_user, user = _as_user()
    top = Path(tempfile.mkdtemp(prefix="drape-image-"))
    proc: subprocess.Popen[bytes] | None = None
    log = None
    try:
        os.chmod(top, 0o755)
        workdir = top / "app"  # WORKDIR /app
        workdir.mkdir()
        copy_context(steps, workdir)
        assert (workdir / "pyproject.toml").is_file() and (workdir / "drape" / "cli.py").is_file()

        python = _python(as_user)
        venv = top / "venv"
        r = run([python, "-m", "venv", str(venv)])
        assert r.returncode == 0, r.stderr
        vpy = str(venv / "bin" / "python")
        print(f"python: {python} ({run([vpy, '-V']).stdout.strip()}); "
              f"{run([vpy, '-m', 'pip', '-V']).stdout.split(' from ')[0]}")
        stamp("venv")

        install = pip_install_args(steps)
        assert "-e" not in install and "--editable" not in install, "the image's install is not editable"
        pip_env = {k: v for k, v in os.environ.items() if k != "PIP_NO_CACHE_DIR"}  # reruns reuse the cache
        r = run([vpy, "-m", "pip", "install", "-q", *install], cwd=workdir, env=pip_env)
        assert r.returncode == 0, r.stdout[-4000:] + r.stderr[-4000:]
        stamp(f"pip install {' '.join(install)}")

        site = next((venv / "lib").glob("python3.*/site-packages"))
        apparent = int(run(["du", "-sb", str(site)]).stdout.split()[0])
        on_disk = int(run(["du", "-sk", str(site)]).stdout.split()[0]) * 1024
        listed = json.loads(run([vpy, "-m", "pip", "list", "--format=json"]).stdout)
        names = sorted(d["name"].lower().replace("_", "-") for d in listed)
        print(f"site-packages: {apparent / 1e6:.0f} MB (du -sb), {on_disk / 2**20:.0f} MiB on disk (du -sk); "
              f"{len(names)} distributions: {' '.join(names)}")
        assert not set(NOT_SERVED) & set(names), f"installed: {set(NOT_SERVED) & set(names)}"
        probe = ("import importlib.util, json, drape; print(json.dumps([drape.__file__, "
                 f"[m for m in {sorted(NOT_SERVED.values())!r} if importlib.util.find_spec(m)]]))")
        where, found = json.loads(run([vpy, "-c", probe], cwd="/").stdout)
        assert not found, f"importable in the image: {found}"
        assert Path(where).is_relative_to(site), f"drape imported from {where}, not the installed package"

        env = {"PATH": f"{venv / 'bin'}:/usr/local/bin:/usr/bin:/bin", "HOME": str(top / "home"), "LANG": "C.UTF-8",
               **{k: v for k, v in os.environ.items() if k.startswith("OPENBLAS_")},
               **env_of(steps)}
        port = free_port()
        env |= {"DRAPE_HOST": "127.0.0.1", "DRAPE_PORT": str(port)}
        (top / "home").mkdir()
        if user is not None:  # the files the image's root installed are readable by its USER; so here
            os.chown(top / "home", user.pw_uid, user.pw_gid)
            for d, dirs, files in os.walk(top):
                for name in dirs + files:
                    p = os.path.join(d, name)
                    if not os.path.islink(p):
                        os.chmod(p, os.lstat(p).st_mode | (0o555 if name in dirs else 0o444))

        # the tools' commands, in an image without them, say which extra to install; motion import needs none
        r = run([*as_user, str(venv / "bin" / "drape"), "render", "--body", "neutral", "--out", str(top / "x.png")],
                env=env, cwd=workdir)
        assert r.returncode != 0 and "pip install 'drape[tools]'" in r.stderr, r.stderr
        assert "Traceback" not in r.stderr, r.stderr
        r = run([*as_user, str(venv / "bin" / "drape"), "motions", "import", str(top / "take.bvh"), "--out",
                 str(top / "x.npz")], env=env, cwd=workdir)
        assert r.returncode != 0 and "take.bvh" in r.stderr and "Traceback" not in r.stderr, r.stderr

        cmd = json.loads(only(steps, "CMD"))
        program = shutil.which(cmd[0], path=env["PATH"])
        assert program == str(venv / "bin" / cmd[0]), f"CMD {cmd} resolves to {program}, not the venv's script"
        log = open(top / "server.log", "wb")  # closed in finally
        proc = subprocess.Popen([*as_user, program, *cmd[1:]], env=env, cwd=workdir, stdout=log,
                                stderr=subprocess.STDOUT)
        print(f"CMD {cmd} as {user.pw_name if user else 'this user'}, DRAPE_PORT={port}")
        base = f"http://127.0.0.1:{port}"
        deadline = time.monotonic() + 180
        status = None
        while time.monotonic() < deadline:
            assert proc.poll() is None, "server exited:\n" + (top / "server.log").read_text()
            try:
                status = httpx.get(f"{base}/readyz", timeout=5).status_code
            except httpx.TransportError:
                status = None
            if status == 200:
                break
            time.sleep(0.5)
        assert status == 200, "not ready in 180 s:\n" + (top / "server.log").read_text()
        stamp("/readyz 200")

        check, check_timeout = healthcheck(steps)
        r = run([*as_user, *check], env=env, cwd=workdir, timeout=check_timeout)
        assert r.returncode == 0, f"HEALTHCHECK exited {r.returncode}: {r.stderr}"
        stamp("HEALTHCHECK exit 0")

        outfit = {"vertices": [[-0.1, 1.2, 0.12], [0.1, 1.2, 0.12], [0.1, 1.0, 0.12], [-0.1, 1.0, 0.12]],
                  "faces": [[0, 1, 2], [0, 2, 3]]}
        a = httpx.post(f"{base}/v1/outfits/animate", json={"outfit": outfit, "motion": {"clip": "walk"}},
                       headers={"accept": "application/x-npz"}, timeout=120)
        assert a.status_code == 200, a.text
        assert a.headers["content-type"].startswith("application/x-npz")
        with np.load(io.BytesIO(a.content), allow_pickle=False) as z:
            verts, faces = z["vertices"], z["faces"]
        from drape.assets.motion import load_clip

        frames = load_clip("walk").num_frames
        assert verts.shape == (frames, 4, 3) and verts.dtype == np.float32 and np.isfinite(verts).all()
        assert faces.tolist() == outfit["faces"]
        assert np.ptp(verts[:, :, 1]) > 0, "the walk moved nothing"
        stamp(f"animate: vertices {verts.shape} {verts.dtype}")

        t_term = time.perf_counter()
        proc.send_signal(signal.SIGTERM)
        code = proc.wait(timeout=25)
        stamp(f"SIGTERM: exit {code} after {time.perf_counter() - t_term:.1f} s")
        text = (top / "server.log").read_text()
        # a graceful stop: uvicorn drains, runs the app's shutdown, then re-raises the SIGTERM it caught
        # (uvicorn >= 0.29), so the exit is -15 (143 from `docker stop`), or 0 from older versions
        assert code in (0, -signal.SIGTERM), text
        assert "Application shutdown complete" in text and "Finished server process" in text, text
        assert "Traceback" not in text, text
        print("server log (tail):\n" + "\n".join(text.splitlines()[-8:]))
    finally:
        if proc is not None and proc.poll() is None:
            proc.kill()
            proc.wait()
        if log is not None:
            log.close()
        shutil.rmtree(top, ignore_errors=True)
