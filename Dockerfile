# syntax=docker/dockerfile:1
# rigserve: build the binary, fetch ONNX Runtime, and assemble a small runtime image.
# scripts/image_build.sh mirrors these steps without Docker (and smoke-tests the
# result); tests/deploy.rs checks that both name the same paths and environment.

# --- build: the toolchain the repository is developed with (rustc 1.95).
FROM rust:1.95-bookworm AS build
WORKDIR /src
COPY Cargo.toml Cargo.lock ./
COPY src src
COPY migrations migrations
# Cache mounts keep the registry and target between builds; the binary is copied out
# of the mount because the mount is not part of the layer.
RUN --mount=type=cache,target=/usr/local/cargo/registry \
    --mount=type=cache,target=/src/target \
    cargo build --release --locked --bin rigserve \
 && install -D target/release/rigserve /out/rigserve

# --- ort: the same library the checkout uses (scripts/fetch_ort.sh, PyPI wheel).
FROM python:3.12-slim-bookworm AS ort
COPY scripts/fetch_ort.sh /fetch_ort.sh
RUN /fetch_ort.sh /out

# --- runtime: glibc and libstdc++ for onnxruntime, CA roots for S3 and webhooks.
FROM debian:bookworm-slim
RUN apt-get update \
 && apt-get install -y --no-install-recommends ca-certificates libstdc++6 \
 && rm -rf /var/lib/apt/lists/* \
 && useradd --system --uid 10001 --user-group --home-dir /app --shell /usr/sbin/nologin rigserve \
 && install -d -o 10001 -g 10001 /data
# Least often changed first, so a code change rebuilds only the last layer.
COPY --from=ort /out/libonnxruntime.so.1.31.1 /app/lib/libonnxruntime.so.1.31.1
COPY models /app/models
COPY deploy/healthcheck.sh /app/healthcheck.sh
COPY --from=build /out/rigserve /app/rigserve
# Every flag has an environment variable; these are the ones the layout fixes.
# Cluster settings (RIGSERVE_ROLE, RIGSERVE_DATABASE_URL, RIGSERVE_BLOB_URL, AWS_*)
# come from the orchestrator (deploy/k8s, deploy/compose.yaml).
ENV RIGSERVE_BIND=0.0.0.0:8080 \
    RIGSERVE_DATA_DIR=/data \
    RIGSERVE_MODELS=/app/models \
    RIGSERVE_ORT_LIB=/app/lib/libonnxruntime.so.1.31.1 \
    RIGSERVE_LOG_JSON=true
WORKDIR /app
# Numeric, so Kubernetes' runAsNonRoot can verify it without reading /etc/passwd.
USER 10001:10001
VOLUME /data
EXPOSE 8080
# SIGTERM starts the drain (--drain, 20 s by default): give `docker stop` more than that.
STOPSIGNAL SIGTERM
HEALTHCHECK --interval=15s --timeout=6s --start-period=30s --retries=3 CMD ["/app/healthcheck.sh"]
ENTRYPOINT ["/app/rigserve"]
CMD ["serve"]
