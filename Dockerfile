# Multi-stage: build with the Rust toolchain, run on a slim Debian as a non-root user.
FROM rust:1-bookworm AS build
WORKDIR /src
COPY . .
# Cargo.lock pins deku 0.19.0 (yanked; adsb_deku needs it): --locked keeps it.
RUN cargo build --release --locked --bin adsb-tracker

FROM debian:bookworm-slim
RUN useradd --system --uid 10001 --no-create-home adsb
COPY --from=build /src/target/release/adsb-tracker /usr/local/bin/adsb-tracker
COPY config/default.toml /etc/adsb-tracker/config.toml
USER adsb
EXPOSE 8080
# Listen on all interfaces inside the container; point [[feeds]] at your readsb.
ENTRYPOINT ["adsb-tracker"]
CMD ["serve", "--config", "/etc/adsb-tracker/config.toml", "--listen", "0.0.0.0:8080"]
