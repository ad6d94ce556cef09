# penumbra-renderer: the path-tracing shading service (renderer/README.md).
#
#   docker build -f deploy/renderer.Dockerfile -t penumbra-renderer .    # from the repository root
#   docker run --rm -v "$PWD/scenes:/scenes:ro" -p 7100:7100 penumbra-renderer
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
RUN cmake --build build -j"$(nproc)" --target penumbra-renderer

FROM debian:12-slim
RUN apt-get update \
 && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
      libembree3-3 libtbb12 libprotobuf32 libspdlog1.10 libfmt9 libssl3 libassimp5 libopenimageio2.4 \
 && rm -rf /var/lib/apt/lists/* \
 && useradd --system --uid 10001 --no-create-home --shell /usr/sbin/nologin penumbra
COPY --from=build /src/build/renderer/penumbra-renderer /usr/local/bin/penumbra-renderer
USER penumbra
EXPOSE 7100
# Healthy = listening on port 7100 (hex 1BBC; state 0A is LISTEN in
# /proc/net/tcp), which the renderer does only once the scene is loaded and
# its BVH built; a large scene takes a while, which the start period covers.
# Reading /proc rather than connecting keeps a session open/close out of the
# log at every check.
HEALTHCHECK --interval=15s --timeout=3s --start-period=120s --retries=3 \
  CMD ["awk", "$4 == \"0A\" && $2 ~ /:1BBC$/ {up = 1} END {exit !up}", "/proc/net/tcp"]
ENTRYPOINT ["penumbra-renderer"]
CMD ["--scene", "/scenes/cornell-box.json", "--listen", "0.0.0.0:7100"]
