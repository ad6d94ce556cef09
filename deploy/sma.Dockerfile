# penumbra-sma: the shading management agent (sma/README.md).
#
#   docker build -f deploy/sma.Dockerfile -t penumbra-sma .    # from the repository root
#   docker run --rm -v "$PWD/scenes:/scenes:ro" -p 127.0.0.1:7200:7200 penumbra-sma \
#     --scene /scenes/cornell-box.json --listen 0.0.0.0:7200 --http 0.0.0.0:7201 --renderer RENDERERS:7100
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
RUN cmake --build build -j"$(nproc)" --target penumbra-sma penumbra-stats

FROM debian:12-slim
RUN apt-get update \
 && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
      libembree3-3 libtbb12 libprotobuf32 libspdlog1.10 libfmt9 libssl3 libassimp5 libopenimageio2.4 \
 && rm -rf /var/lib/apt/lists/* \
 && useradd --system --uid 10001 --no-create-home --shell /usr/sbin/nologin penumbra \
 && install -d -o penumbra -g penumbra -m 0750 /var/lib/penumbra-sma
# --cache-dir for the compose file's sma-cache volume: a new named volume
# takes this directory's owner, so the non-root SMA can write its snapshots.
COPY --from=build /src/build/sma/penumbra-sma /usr/local/bin/penumbra-sma
COPY --from=build /src/build/common/tools/penumbra-stats /usr/local/bin/penumbra-stats
USER penumbra
EXPOSE 7200 7201
# Healthy = ready: /readyz on the operator HTTP endpoint answers 200 once
# the scene is loaded AND at least one renderer is connected (an SMA with no
# renderer would leave every client waiting). The command line must give
# --http 0.0.0.0:7201 (deploy/docker-compose.yml does). penumbra-stats is the
# project's own HTTP client (the slim image has no curl).
HEALTHCHECK --interval=15s --timeout=3s --start-period=120s --retries=3 \
  CMD ["penumbra-stats", "--ready", "--timeout", "2", "127.0.0.1:7201"]
ENTRYPOINT ["penumbra-sma"]
