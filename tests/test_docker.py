"""The container files, without a Docker engine: the Dockerfile linted (hadolint) and its install
steps run in a clean virtual environment, the entrypoint's CPU-quota sizing, compose.yaml and the
Kubernetes manifest parsed and checked."""

import json
import os
import shlex
import shutil
import subprocess
import sys
import time
from pathlib import Path

import pytest
import yaml

from .serving import free_port

ROOT = Path(__file__).resolve().parents[1]
DOCKER = ROOT / "docker"
ENTRYPOINT = DOCKER / "entrypoint.sh"


def _tool(name: str) -> str:
    path = Path(sys.executable).parent / name
    if path.exists():
        return str(path)
    found = shutil.which(name)
    if not found:
        pytest.fail(f"{name} is not installed; it comes with the test extra (`make install`)")
    return found


def _instructions() -> list[tuple[str, str]]:
    """(INSTRUCTION, arguments) of docker/Dockerfile, continuation lines joined, comments dropped."""
    out, buf = [], ""
    for line in (DOCKER / "Dockerfile").read_text().splitlines():
        if not buf and (not line.strip() or line.lstrip().startswith("#")):
            continue
        if line.lstrip().startswith("#"):
            continue
        buf += line.rstrip()
        if buf.endswith("\\"):
            buf = buf[:-1] + " "
            continue
        word, _, rest = buf.strip().partition(" ")
        out.append((word.upper(), rest.strip()))
        buf = ""
    return out


def test_dockerfile_and_entrypoint_lint_clean():
    lint = subprocess.run([_tool("hadolint"), "--no-color", str(DOCKER / "Dockerfile")],
                          capture_output=True, text=True)
    assert lint.returncode == 0, lint.stdout + lint.stderr
    check = subprocess.run([_tool("shellcheck"), str(ENTRYPOINT)], capture_output=True, text=True)
    assert check.returncode == 0, check.stdout + check.stderr


def test_dockerfile_runs_unprivileged_with_health_check_and_serves_by_default():
    ins = _instructions()
    words = [w for w, _ in ins]
    assert words[0] == "FROM" and ins[0][1].startswith("python:3.11-slim")
    user = [a for w, a in ins if w == "USER"]
    assert user and user[-1] not in ("root", "0")
    health = next(a for w, a in ins if w == "HEALTHCHECK")
    assert "/readyz" in health
    entry = json.loads(next(a for w, a in ins if w == "ENTRYPOINT"))
    cmd = json.loads(next(a for w, a in ins if w == "CMD"))
    assert entry == ["relight-entrypoint"] and cmd[0] == "serve" and "0.0.0.0" in cmd
    env = " ".join(a for w, a in ins if w == "ENV")
    assert "POCL_CACHE_DIR" in env
    assert any(w == "EXPOSE" and a == "8000" for w, a in ins)


def test_every_package_folder_reaches_the_image():
    """Each folder pyproject maps onto a package is COPY'd by the Dockerfile and let through by its
    .dockerignore (which leaves out everything it does not name): a folder missed in either
    breaks the image's install."""
    import tomllib

    dirs = tomllib.loads((ROOT / "pyproject.toml").read_text())["tool"]["setuptools"]["package-dir"]
    tops = {d.split("/")[0] for d in dirs.values()}
    copied = {a.split()[0] for w, a in _instructions() if w == "COPY" and not a.startswith("--")}
    allowed = {line[1:] for line in (DOCKER / "Dockerfile.dockerignore").read_text().splitlines()
               if line.startswith("!")}
    assert tops - copied == set(), f"package folders the Dockerfile does not COPY: {sorted(tops - copied)}"
    assert tops - allowed == set(), f"package folders .dockerignore leaves out: {sorted(tops - allowed)}"


def _entrypoint_env(tmp_path, files: dict[str, str], **env) -> dict[str, str]:
    root = tmp_path / "cgroup"
    for name, text in files.items():
        (root / name).parent.mkdir(parents=True, exist_ok=True)
        (root / name).write_text(text)
    root.mkdir(exist_ok=True)
    base = {k: v for k, v in os.environ.items() if not k.startswith("POCL_")}
    run = subprocess.run(["sh", str(ENTRYPOINT)], capture_output=True, text=True, check=True,
                         env=dict(base, RELIGHT_CGROUP_ROOT=str(root), RELIGHT_COMMAND="env", **env))
    return dict(line.split("=", 1) for line in run.stdout.splitlines() if "=" in line)


@pytest.mark.parametrize("files, expected", [
    ({"cpu.max": "100000 100000\n"}, 1),  # cgroup v2, one CPU
    ({"cpu.max": "50000 100000\n"}, 1),  # half a CPU rounds up to one thread
    ({"cpu.max": "150000 100000\n"}, 2),  # 1.5 CPUs -> 2 (capped by nproc below)
    ({"cpu.max": "max 100000\n"}, None),  # no quota: every allowed CPU
    ({"cpu/cpu.cfs_quota_us": "100000\n", "cpu/cpu.cfs_period_us": "100000\n"}, 1),  # cgroup v1
    ({"cpu/cpu.cfs_quota_us": "-1\n", "cpu/cpu.cfs_period_us": "100000\n"}, None),  # v1, no quota
    ({"cpu.max": "lots 0\n"}, None),  # unreadable: ignored, with a warning
    ({}, None),  # no cgroup files at all
])
def test_entrypoint_sizes_pocl_to_the_cpu_quota(tmp_path, files, expected):
    nproc = len(os.sched_getaffinity(0))
    want = str(min(expected, nproc) if expected else nproc)
    env = _entrypoint_env(tmp_path, files)
    assert env["POCL_CPU_MAX_CU_COUNT"] == want and env["POCL_MAX_PTHREAD_COUNT"] == want


def test_entrypoint_keeps_thread_counts_the_user_set(tmp_path):
    env = _entrypoint_env(tmp_path, {"cpu.max": "100000 100000\n"}, POCL_CPU_MAX_CU_COUNT="7")
    assert env["POCL_CPU_MAX_CU_COUNT"] == "7" and env["POCL_MAX_PTHREAD_COUNT"] == "1"


@pytest.mark.slow
def test_dockerfile_install_steps_in_a_clean_venv_serve_a_bundle(tmp_path, small_bundle):
    """The image's build, minus the engine: only the files the Dockerfile COPYs, its pip install
    in a fresh virtual environment (with pip's cache, so no --no-cache-dir), then its entrypoint
    and command with a one-CPU quota; the HEALTHCHECK command must report ready and PoCL must
    run with one compute unit."""
    import httpx

    ins = _instructions()
    src = tmp_path / "src"
    src.mkdir()
    for word, args in ins:
        if word != "COPY":
            continue
        *sources, dest = shlex.split(args)
        for s in sources:
            if dest.startswith("/"):  # an absolute path in the image, kept under tmp_path/image
                target = tmp_path / "image" / dest.lstrip("/")
            elif dest.endswith("/") or dest == ".":
                target = src / dest / Path(s).name
            else:
                target = src / dest
            target.parent.mkdir(parents=True, exist_ok=True)
            if (ROOT / s).is_dir():
                shutil.copytree(ROOT / s, target, ignore=shutil.ignore_patterns("__pycache__", "*.egg-info"))
            else:
                shutil.copy2(ROOT / s, target)
    pip_line = next(a for w, a in ins if w == "RUN" and "pip install" in a)
    pip_args = shlex.split(pip_line.split("&&")[0])
    assert pip_args[:2] == ["pip", "install"], pip_line
    pip_args = [a for a in pip_args[2:] if a != "--no-cache-dir"]

    venv = tmp_path / "venv"
    subprocess.run([sys.executable, "-m", "venv", str(venv)], check=True)
    inst = subprocess.run([str(venv / "bin" / "python"), "-m", "pip", "install", "--quiet", *pip_args],
                          cwd=src, capture_output=True, text=True)
    assert inst.returncode == 0, inst.stderr[-3000:]
    entry = tmp_path / "image" / "usr" / "local" / "bin" / "relight-entrypoint"
    assert os.access(entry, os.X_OK), "docker/entrypoint.sh must be executable (git tracks the mode)"

    cgroup = tmp_path / "cgroup"
    cgroup.mkdir()
    (cgroup / "cpu.max").write_text("100000 100000\n")
    port = free_port()
    cmd = json.loads(next(a for w, a in ins if w == "CMD"))
    cmd = [str(small_bundle.path) if a.endswith(".bundle") else a for a in cmd]
    cmd[cmd.index("--port") + 1] = str(port)
    cmd[cmd.index("--host") + 1] = "127.0.0.1"
    env = {k: v for k, v in os.environ.items() if not k.startswith(("POCL_", "VIRTUAL_ENV"))}
    env.update(PATH=f"{venv / 'bin'}:/usr/bin:/bin", RELIGHT_CGROUP_ROOT=str(cgroup), RELIGHT_LOG_LEVEL="warning",
               POCL_CACHE_DIR=str(tmp_path / "pocl-cache"))
    health = json.loads(next(a for w, a in ins if w == "HEALTHCHECK").split("CMD", 1)[1])
    health = [str(venv / "bin" / "python") if a == "python" else a.replace(":8000/", f":{port}/") for a in health]
    proc = subprocess.Popen([str(entry), *cmd], cwd=tmp_path, env=env, stdout=subprocess.DEVNULL,
                            stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.time() + 120
        while subprocess.run(health, capture_output=True).returncode != 0:
            assert proc.poll() is None, f"the service exited: {proc.stderr.read()[-2000:]}"
            assert time.time() < deadline, "the health check never passed"
            time.sleep(0.5)
        ready = httpx.get(f"http://127.0.0.1:{port}/readyz").json()
        assert ready["compute_units"] == 1, ready
        page = httpx.get(f"http://127.0.0.1:{port}/")  # package data (the browser page) installed
        assert page.status_code == 200 and "<video" in page.text
    finally:
        proc.terminate()
        proc.wait(timeout=20)
        proc.stderr.close()


def test_compose_builds_from_the_repository_and_limits_cpus():
    doc = yaml.safe_load((DOCKER / "compose.yaml").read_text())
    svc = doc["services"]["relight"]
    context = (DOCKER / svc["build"]["context"]).resolve()
    assert context == ROOT and (context / svc["build"]["dockerfile"]).is_file()
    assert float(svc["cpus"]) >= 1 and "/readyz" in " ".join(svc["healthcheck"]["test"])
    assert any(p.endswith(":8000") for p in svc["ports"])


def _cpu_cores(q: str) -> float:
    q = str(q)
    return float(q[:-1]) / 1000 if q.endswith("m") else float(q)


def test_k8s_manifest_probes_limits_and_read_only_bundle():
    docs = {d["kind"]: d for d in yaml.safe_load_all((DOCKER / "k8s.yaml").read_text()) if d}
    dep, svc = docs["Deployment"], docs["Service"]
    spec = dep["spec"]
    assert spec["replicas"] >= 2
    labels = spec["template"]["metadata"]["labels"]
    assert spec["selector"]["matchLabels"].items() <= labels.items()
    assert svc["spec"]["selector"].items() <= labels.items()
    (c,) = spec["template"]["spec"]["containers"]
    port = {p["name"]: p["containerPort"] for p in c["ports"]}
    assert port["http"] == 8000 and svc["spec"]["ports"][0]["targetPort"] in ("http", 8000)
    assert c["readinessProbe"]["httpGet"]["path"] == "/readyz"
    assert c["livenessProbe"]["httpGet"]["path"] == "/livez"
    assert c["startupProbe"]["httpGet"]["path"] == "/readyz"
    # Whole-core CPU limit; PoCL's compute units and threads follow that limit.
    limit = _cpu_cores(c["resources"]["limits"]["cpu"])
    assert limit == int(limit) >= 1 and _cpu_cores(c["resources"]["requests"]["cpu"]) == limit
    env = {e["name"]: e for e in c["env"]}
    for name in ("POCL_CPU_MAX_CU_COUNT", "POCL_MAX_PTHREAD_COUNT"):
        ref = env[name].get("valueFrom", {}).get("resourceFieldRef")
        assert (ref and ref["resource"] == "limits.cpu" and str(ref.get("divisor", "1")) == "1") \
            or int(env[name]["value"]) == limit, env[name]
    # The bundle the service reads is mounted read-only.
    bundle = c["args"][c["args"].index("serve") + 1]
    (mount,) = [m for m in c["volumeMounts"] if bundle.startswith(m["mountPath"].rstrip("/") + "/")]
    assert mount["readOnly"] is True
    (vol,) = [v for v in spec["template"]["spec"]["volumes"] if v["name"] == mount["name"]]
    assert vol.get("persistentVolumeClaim", {}).get("readOnly", True) is True
    assert spec["template"]["spec"]["securityContext"]["runAsNonRoot"] is True
