# facerecon container image: `facerecon-server` (the gRPC service) and the `facerecon`
# command. Runs CPU-only (Mesa's lavapipe for Vulkan) and on an NVIDIA GPU through the
# NVIDIA container toolkit (`--gpus all`: the toolkit mounts the driver's Vulkan ICD).
#
#   docker build -t facerecon .
#   docker run --rm -p 50051:50051 -p 9464:9464 -v "$PWD/models:/models:ro" facerecon
#
# The face model is mounted, not baked in: `scripts/setup` builds
# models/ict-face-light.safetensors from ICT-FaceKit; FACERECON_MODEL names it. The face
# detector (opencv-data) and the 68-point landmark model (libdlib-data) come from Debian;
# the released encoder weights (weights/) and ONNX Runtime (PyPI's wheel) are baked in.
# scripts/docker-check builds this image, serves a request from it and stops it.

FROM rust:1.95-bookworm AS build
# libjpeg-turbo's TurboJPEG library: JPEG decoding (facerecon-vision links it via pkg-config).
RUN apt-get update \
 && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends libturbojpeg0-dev pkg-config \
 && rm -rf /var/lib/apt/lists/*
WORKDIR /src
# ONNX Runtime's C library (the encoder's CPU path and the ONNX plug-ins load it at run
# time), taken from PyPI's onnxruntime wheel as on a host.
RUN apt-get update \
 && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends python3-pip \
 && rm -rf /var/lib/apt/lists/*
COPY scripts/install-onnxruntime scripts/
RUN FACERECON_ORT_HOME=/opt/onnxruntime scripts/install-onnxruntime >/dev/null \
 && cp -L /opt/onnxruntime/libonnxruntime.so /opt/libonnxruntime.so
COPY . .
RUN cargo build --release --locked -p facerecon-server -p facerecon-client \
 && strip target/release/facerecon-server target/release/facerecon

FROM debian:bookworm-slim
RUN apt-get update \
 && DEBIAN_FRONTEND=noninteractive apt-get install -y --no-install-recommends \
      mesa-vulkan-drivers libvulkan1 opencv-data libdlib-data libturbojpeg0 ca-certificates \
 && rm -rf /var/lib/apt/lists/* \
 && useradd --system --uid 10001 --no-create-home facerecon
COPY --from=build /src/target/release/facerecon-server /src/target/release/facerecon /usr/local/bin/
# The released encoder weights (weights/README.md), which the server loads by default, and
# ONNX Runtime, which runs them on the CPU.
COPY weights/*.safetensors /usr/local/share/facerecon/weights/
COPY --from=build /opt/libonnxruntime.so /usr/local/lib/facerecon/libonnxruntime.so
ENV FACERECON_LISTEN=0.0.0.0:50051 \
    FACERECON_WEIGHTS_DIR=/usr/local/share/facerecon/weights \
    ORT_DYLIB_PATH=/usr/local/lib/facerecon/libonnxruntime.so \
    FACERECON_METRICS_LISTEN=0.0.0.0:9464 \
    FACERECON_MODEL=/models/ict-face-light.safetensors \
    FACERECON_LOG_FORMAT=json \
    XDG_RUNTIME_DIR=/tmp \
    WGPU_BACKEND=vulkan \
    NVIDIA_DRIVER_CAPABILITIES=compute,utility,graphics
USER 10001
EXPOSE 50051 9464
ENTRYPOINT ["facerecon-server"]
