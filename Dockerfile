# facerecon container image: the `facerecon` command with everything it needs at run time,
# rendering on CPU through Mesa's lavapipe (no GPU required).
#
#   docker build -t facerecon .
#   docker run --rm -v "$PWD/out:/out" facerecon synth --count 8 -o /out
#
# The face model is built from an ICT-FaceKit folder at run time or mounted:
#   docker run --rm -v /path/to/ICT-FaceKit:/ict -v "$PWD/models:/models" facerecon \
#     model import-ict --source /ict -o /models/ict-face-light.safetensors

FROM rust:1.95-bookworm AS build
# libjpeg-turbo's TurboJPEG library: JPEG decoding (facerecon-vision links it via pkg-config).
RUN apt-get update \
 && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends libturbojpeg0-dev pkg-config \
 && rm -rf /var/lib/apt/lists/*
WORKDIR /src
COPY . .
RUN cargo build --release --locked -p facerecon-client \
 && strip target/release/facerecon

FROM debian:bookworm-slim
RUN apt-get update \
 && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
      mesa-vulkan-drivers libvulkan1 opencv-data libdlib-data libturbojpeg0 ca-certificates \
 && rm -rf /var/lib/apt/lists/*
COPY --from=build /src/target/release/facerecon /usr/local/bin/facerecon
ENV XDG_RUNTIME_DIR=/tmp WGPU_BACKEND=vulkan
ENTRYPOINT ["facerecon"]
