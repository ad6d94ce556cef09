# penumbra-client, for headless walkthroughs (scripted camera path,
# statistics, screenshots) on a machine without a display: OpenGL through
# Mesa's software rasterizer (llvmpipe). An interactive client runs on the
# user's own machine, not in a container.
#
#   docker build -f deploy/client.Dockerfile -t penumbra-client .    # from the repository root
#   docker run --rm -v "$PWD/scenes:/scenes:ro" penumbra-client --connect SMA_HOST:7200 --headless --gl egl \
#     --camera-path /scenes/cornell-box.json#walk --until-converged --screenshot /out/penumbra.png
#
# Built as renderer.Dockerfile describes, with the GL client switched on: the
# build stage adds install-deps.sh's GL development packages, the runtime
# stage Mesa's drivers, which the GL libraries load at run time (ldd does not
# list them). tests/deploy/dockerfile_test.sh checks both lists.

FROM debian:12 AS build
RUN apt-get update \
 && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
      cmake g++ make pkg-config ca-certificates \
      libboost-dev libssl-dev libprotobuf-dev protobuf-compiler libembree-dev libopenimageio-dev \
      libglm-dev libspdlog-dev libassimp-dev libcli11-dev nlohmann-json3-dev libtbb-dev \
      libglfw3-dev libepoxy-dev libegl-dev libimgui-dev \
 && rm -rf /var/lib/apt/lists/*
WORKDIR /src
COPY . .
RUN cmake -S . -B build -DCMAKE_BUILD_TYPE=RelWithDebInfo \
      -DPENUMBRA_BUILD_TESTS=OFF -DPENUMBRA_BUILD_BENCH=OFF -DPENUMBRA_BUILD_CLIENT_GUI=ON
RUN cmake --build build -j"$(nproc)" --target penumbra-client

FROM debian:12-slim
RUN apt-get update \
 && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
      libprotobuf32 libspdlog1.10 libfmt9 libssl3 libassimp5 libopenimageio2.4 \
      libglfw3 libepoxy0 libegl1 libegl-mesa0 libgl1 libglx-mesa0 libgl1-mesa-dri libstb0 \
 && rm -rf /var/lib/apt/lists/* \
 && useradd --system --uid 10001 --create-home --shell /usr/sbin/nologin penumbra
COPY --from=build /src/build/client/penumbra-client /usr/local/bin/penumbra-client
# Screenshots and statistics go here (a volume in deploy/docker-compose.yml;
# a new named volume takes this directory's owner).
RUN install -d -o penumbra -g penumbra /out
USER penumbra
WORKDIR /out
ENTRYPOINT ["penumbra-client"]
