# The image examples/k8s/gen-job.yaml runs: the causalcity binary (with V-CDN
# export) on PATH and the repository's configs/ under /opt/causalcity.
#
#   docker build -t causalcity:latest .
#   docker run --rm -v "$PWD/data:/data" causalcity:latest \
#       causalcity gen --spec /opt/causalcity/configs/ci-city.json --out /data/ci-city
#
# See examples/k8s/README.md for loading it into a cluster.
FROM rust:1-bookworm AS build
RUN apt-get update -qq \
    && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends libhdf5-dev pkg-config \
    && rm -rf /var/lib/apt/lists/*
WORKDIR /src
COPY Cargo.toml Cargo.lock ./
COPY src ./src
COPY benches ./benches
# A member of the workspace (the Python package): cargo reads its manifest.
COPY python/Cargo.toml ./python/Cargo.toml
COPY python/src ./python/src
RUN cargo build --release --locked --features hdf5 --bin causalcity

FROM debian:bookworm-slim
RUN apt-get update -qq \
    && DEBIAN_FRONTEND=noninteractive apt-get install -y -qq --no-install-recommends libhdf5-103-1 \
    && rm -rf /var/lib/apt/lists/*
COPY --from=build /src/target/release/causalcity /usr/local/bin/causalcity
COPY configs /opt/causalcity/configs
WORKDIR /data
CMD ["causalcity", "--help"]
