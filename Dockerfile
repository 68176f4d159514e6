# irrrd, the iRRR loop-closing daemon, and its client tools in a small Debian bookworm image.
# docs/daemon.md ("Docker") has the commands a user runs; in short:
#
#   docker build -t irrrd .
#   docker volume create irrrd-state
#   docker run --rm --network host -v irrrd-state:/var/lib/irrrd irrrd
#   docker run --rm --network host irrrd irrr-listen --idle-exit 10       (a client tool)
#
# LCM's udpm:// transport is UDP multicast: use the host network (or a macvlan network) so that
# irrrd and the robots share the multicast group; Docker's default bridge does not forward it.
# The image sets LCM_DEFAULT_URL (below): ttl=0 (this host only) and a 2 MB socket receive buffer;
# for robots on other hosts pass -e LCM_DEFAULT_URL='udpm://239.255.76.67:7667?ttl=1&recv_buf_size=2097152'
# (or --lcm-url, or "daemon.lcm_url" in a mounted config). The kernel caps the buffer at the
# host's net.core.rmem_max: raise it on the host (sysctl -w net.core.rmem_max=2097152). The host
# also needs a multicast route on the robot interface.
# Arguments after the image name are appended to irrrd's command line; a first argument irrr-<tool>
# runs that tool instead (config/docker-entrypoint.sh). `docker stop` sends SIGTERM: irrrd applies
# what it has received, publishes a STOPPING status and exits 0. `docker kill -s HUP` reloads the
# config.
# No "# syntax=" line: the Dockerfile uses nothing beyond the builder's built-in frontend, so an
# offline BuildKit build fetches nothing.

FROM debian:bookworm AS build
# liblcm-bin for lcm-gen, libglib2.0-dev because lcm.pc requires glib-2.0; libopenblas0-serial is
# the BLAS that CHOLMOD uses on the developers' machines (tools/setup), kept the same here;
# zlib1g-dev for the journal's CRC-32, libcpp-httplib-dev for irrr-view.
# No catch2: the tests are not built (see below).
RUN apt-get update \
 && apt-get install -y --no-install-recommends \
      cmake g++ make pkg-config \
      liblcm-dev liblcm-bin libglib2.0-dev \
      libeigen3-dev libsuitesparse-dev libopenblas0-serial \
      libboost-dev libfmt-dev libcli11-dev nlohmann-json3-dev libspdlog-dev \
      zlib1g-dev libcpp-httplib-dev \
 && rm -rf /var/lib/apt/lists/*
WORKDIR /src
COPY . .
# Tests off to keep the image build fast; they run in CI, and the netns ones could not run here
# anyway (docker build does not allow unshare).
RUN cmake -S . -B build -DCMAKE_BUILD_TYPE=Release -DIRRR_BUILD_TESTS=OFF \
      -DIRRR_BUILD_JAVA_TYPES=OFF \
 && cmake --build build -j"$(nproc)" \
 && cmake --install build --prefix /opt/irrr

FROM debian:bookworm-slim AS runtime
# Only the shared libraries the installed binaries need (ldd + dpkg -S on the build output):
# liblcm1 (which pulls in libglib2.0-0), libspdlog1.10 + libfmt9, libcholmod3 (pulls in the rest of
# SuiteSparse, metis and libgomp1). Naming libopenblas0-serial makes apt pick it for CHOLMOD's
# libblas.so.3/liblapack.so.3 instead of the slow reference BLAS (libblas3/liblapack3).
# libcpp-httplib0.11 is for irrr-view, the live map, copied with the other clients.
RUN apt-get update \
 && apt-get install -y --no-install-recommends \
      liblcm1 libglib2.0-0 libspdlog1.10 libfmt9 libcholmod3 libopenblas0-serial \
      libcpp-httplib0.11 \
 && rm -rf /var/lib/apt/lists/* \
 && groupadd --gid 10001 irrrd \
 && useradd --uid 10001 --gid irrrd --no-create-home --home-dir /nonexistent \
      --shell /usr/sbin/nologin irrrd \
 && install -d -o 10001 -g 10001 /var/lib/irrrd
# Only bin/: irrrd plus the installed clients (irrr-inject, irrr-listen, ...) for checks in place.
COPY --from=build /opt/irrr/bin/ /usr/local/bin/
COPY config/irrrd.json /etc/irrrd/irrrd.json
COPY config/docker-entrypoint.sh /usr/local/bin/irrrd-entrypoint
# The URL of every program in the image unless its config or command line names one: LCM's
# default group, this host only (ttl=0), and a 2 MB receive buffer instead of the kernel's
# default (~208 kB; LCM 1.3.1 asks for nothing more unless the URL does), which overflows during
# bursts while a step runs.
ENV LCM_DEFAULT_URL="udpm://239.255.76.67:7667?ttl=0&recv_buf_size=2097152"
# A numeric user, so that runtimes can check "not root" without reading /etc/passwd.
USER 10001:10001
# irrrd handles SIGTERM/SIGINT/SIGHUP itself (signalfd) and starts no child processes, so it can
# run as PID 1 without an init (the entry point execs it).
STOPSIGNAL SIGTERM
# The journal: mount a volume here (docker run -v irrrd-state:/var/lib/irrrd ...) so that a
# restarted container rebuilds the state it had. A named volume takes the owner of this folder
# (uid 10001); a bind-mounted host folder keeps its own, so it must belong to uid 10001:
#   sudo install -d -o 10001 -g 10001 /srv/irrrd && docker run ... -v /srv/irrrd:/var/lib/irrrd ...
# (otherwise irrrd exits 74: journal unreadable).
VOLUME /var/lib/irrrd
ENTRYPOINT ["/usr/local/bin/irrrd-entrypoint"]
