# penumbra-renderer: the path-tracing shading service (renderer/README.md).
#
#   docker build -f deploy/renderer.Dockerfile -t penumbra-renderer .    # from the repository root
#   docker run --rm -v "$PWD/scenes:/scenes:ro" -p 7100:7100 -p 7101:7101 penumbra-renderer
#   penumbra-stats 127.0.0.1:7101    # its metrics (or curl http://127.0.0.1:7101/metrics)
#
# The build stage installs the build packages of scripts/install-deps.sh and
# configures and builds as scripts/build.sh does (tests, benchmarks and the GL
# client left out). The runtime stage holds only the shared libraries the
# executable links. tests/deploy/dockerfile_test.sh checks both lists: every
# build package is one install-deps.sh installs, and every library that ldd
# lists for the executable comes from a runtime package or its dependencies.
# renderer.Dockerfile and sma.Dockerfile share every build step but the last,
# so building both images compiles the common libraries once.

FROM debian:12 AS build
RUN apt-get update \
 && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
      cmake g++ make pkg-config ca-certificates \
      libboost-dev libssl-dev libprotobuf-dev protobuf-compiler libembree-dev libopenimageio-dev \
      libglm-dev libspdlog-dev libassimp-dev libcli11-dev nlohmann-json3-dev libtbb-dev \
 && rm -rf /var/lib/apt/lists/*
WORKDIR /src
COPY . .
RUN cmake -S . -B build -DCMAKE_BUILD_TYPE=RelWithDebInfo \
      -DPENUMBRA_BUILD_TESTS=OFF -DPENUMBRA_BUILD_BENCH=OFF -DPENUMBRA_BUILD_CLIENT_GUI=OFF
RUN cmake --build build -j"$(nproc)" --target penumbra-renderer penumbra-stats

FROM debian:12-slim
RUN apt-get update \
 && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
      libembree3-3 libtbb12 libprotobuf32 libspdlog1.10 libfmt9 libssl3 libassimp5 libopenimageio2.4 \
 && rm -rf /var/lib/apt/lists/* \
 && useradd --system --uid 10001 --no-create-home --shell /usr/sbin/nologin penumbra
COPY --from=build /src/build/renderer/penumbra-renderer /usr/local/bin/penumbra-renderer
COPY --from=build /src/build/common/tools/penumbra-stats /usr/local/bin/penumbra-stats
USER penumbra
EXPOSE 7100 7101
# Healthy = ready: /readyz on the operator HTTP endpoint (--http, below)
# answers 200, which the renderer does once the scene is loaded and its BVH
# built, and no longer while it drains on SIGTERM. A large scene takes a
# while to load, which the start period covers. penumbra-stats is the
# project's own HTTP client (the slim image has no curl).
HEALTHCHECK --interval=15s --timeout=3s --start-period=120s --retries=3 \
  CMD ["penumbra-stats", "--ready", "--timeout", "2", "127.0.0.1:7101"]
ENTRYPOINT ["penumbra-renderer"]
CMD ["--scene", "/scenes/cornell-box.json", "--listen", "0.0.0.0:7100", "--http", "0.0.0.0:7101"]
