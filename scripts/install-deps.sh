#!/usr/bin/env bash
# Installs Penumbra's build and test dependencies from Debian 12 packages.
# Idempotent: installs only what is missing, and runs apt-get update only then.
set -euo pipefail

packages=(
  # toolchain
  cmake g++ make pkg-config ca-certificates
  # libFuzzer targets (scripts/fuzz.sh): clang and its runtimes (libFuzzer, ASan, UBSan)
  clang libclang-rt-14-dev
  # libraries
  libboost-dev libprotobuf-dev protobuf-compiler libembree-dev libopenimageio-dev
  libglfw3-dev libglm-dev libspdlog-dev libassimp-dev libcli11-dev nlohmann-json3-dev
  libtbb-dev libepoxy-dev libegl-dev
  # the client's HUD: Dear ImGui (with its GLFW and OpenGL 3 backends) and a
  # readable font (DejaVu Sans; ImGui's built-in font is the fallback)
  libimgui-dev fonts-dejavu-core
  # TLS on every hop (Boost.Asio's ssl::stream); the openssl CLI makes test certificates
  libssl-dev openssl
  # OpenImageIO's CMake package checks that its tools (iconvert, ...) exist
  openimageio-tools
  # tests and benchmarks
  libgtest-dev libgmock-dev libbenchmark-dev
  # headless OpenGL (client tests, screenshots)
  xvfb xauth libgl1-mesa-dri libglx-mesa0
  # the window client's drag test (tests/client_test.cpp) drives the mouse and keys
  xdotool
  # multi-host tests and deployment checks
  iproute2 docker-compose yamllint
)
# Node.js and npm run the offline Kubernetes manifest validation
# (deploy/k8s/validate, `npm ci`). Debian's own packages on a fresh machine;
# a machine that already has both commands from another Node.js distribution
# (whose nodejs package conflicts with Debian's npm) keeps them.
if ! command -v node >/dev/null 2>&1 || ! command -v npm >/dev/null 2>&1; then
  packages+=(nodejs npm)
fi

missing=()
for p in "${packages[@]}"; do
  if ! dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed"; then
    missing+=("$p")
  fi
done

if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#packages[@]} packages present"
  exit 0
fi

echo "install-deps: installing ${missing[*]}"
sudo=""
if [ "$(id -u)" -ne 0 ]; then
  if command -v sudo >/dev/null 2>&1; then sudo="sudo"; else
    echo "install-deps: need root (or sudo) to install: ${missing[*]}" >&2
    exit 1
  fi
fi
export DEBIAN_FRONTEND=noninteractive
# apt's and dpkg's chatter goes to a log; on failure its end is shown.
log="$(mktemp /tmp/penumbra-install-deps-XXXXXX.log)"
if ! { $sudo apt-get update -qq && $sudo apt-get install -y -qq --no-install-recommends "${missing[@]}"; } >"$log" 2>&1; then
  tail -n 30 "$log" >&2
  echo "install-deps: apt-get failed; full log in $log" >&2
  exit 1
fi
echo "install-deps: installed ${#missing[@]} package(s) (log in $log)"
