# penumbra-sma: the shading management agent (sma/README.md).
#
#   docker build -f deploy/sma.Dockerfile -t penumbra-sma .    # from the repository root
#   docker run --rm -v "$PWD/scenes:/scenes:ro" -p 127.0.0.1:7200:7200 penumbra-sma \
#     --scene /scenes/cornell-box.json --listen 0.0.0.0:7200 --renderer RENDERERS:7100
#
# The SMA has no useful default for --renderer, so the command line is the
# caller's: deploy/docker-compose.yml gives it the renderer service's DNS name,
# which the SMA resolves to every replica and re-resolves every
# --resolve-interval seconds.
#
# The build stage is renderer.Dockerfile's, step for step, up to the target it
# builds (see there; tests/deploy/dockerfile_test.sh checks both files).

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
RUN cmake --build build -j"$(nproc)" --target penumbra-sma

FROM debian:12-slim
RUN apt-get update \
 && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
      libembree3-3 libtbb12 libprotobuf32 libspdlog1.10 libfmt9 libssl3 libassimp5 libopenimageio2.4 \
 && rm -rf /var/lib/apt/lists/* \
 && useradd --system --uid 10001 --no-create-home --shell /usr/sbin/nologin penumbra
COPY --from=build /src/build/sma/penumbra-sma /usr/local/bin/penumbra-sma
USER penumbra
EXPOSE 7200
# Healthy = listening on port 7200 (hex 1C20; state 0A is LISTEN in
# /proc/net/tcp, read rather than connected to, to keep the log clean): the
# scene is loaded and the SMA takes clients, even while no renderer is
# connected yet (views then wait for shading).
HEALTHCHECK --interval=15s --timeout=3s --start-period=120s --retries=3 \
  CMD ["awk", "$4 == \"0A\" && $2 ~ /:1C20$/ {up = 1} END {exit !up}", "/proc/net/tcp"]
ENTRYPOINT ["penumbra-sma"]
