# gazehdr gaze daemon, for the machine the eye tracker is plugged into: reads a USB HID tracker
# (usage page 0x12, through the kernel's hidraw driver), detects fixations and blinks, keeps the
# session log and streams to a gazehdr server. gazehdr[daemon] only: no pyopencl, no simulation.
#
#   docker build -f docker/daemon.Dockerfile -t gazehdr-daemon .          (from the repo root)
#   docker run --rm --device /dev/hidraw0 --group-add "$(getent group plugdev | cut -d: -f3)" \
#     -e GAZEHDR_TOKEN -v gazehdr-daemon-data:/data gazehdr-daemon \
#     --source hid --server ws://SERVER:8000
#
# Arguments are `gazehdr daemon`'s (`--help` lists them); without any it runs `--source hid`,
# which waits for a tracker, and takes the server from GAZEHDR_SERVER. The token comes from
# GAZEHDR_TOKEN, never from the image. Each run records to a new gaze-YYYYmmddTHHMMSSZ.jsonl in
# GAZEHDR_RECORD_DIR (/data/recordings), whether or not the server can be reached.
#
# Map the hidraw node under its own name (--device /dev/hidraw3, not /dev/hidraw3:/dev/hidraw0):
# hidapi finds devices through sysfs, which names the host's node. The host's udev rule
# (docker/udev/) gives usage-page-0x12 trackers to group plugdev; --group-add passes the host's
# plugdev gid in case it differs from the image's (46 on Debian and Ubuntu). See docker/README.md.

# Build arguments (docker/README.md, "Offline builds"):
#   BASE           the image both stages start from: python:3.11-slim-bookworm, or a Debian
#                  bookworm base made from Debian's packages by docker/make-base.sh where no
#                  image registry can be reached (it prints the tag to pass here).
#   PIP_INDEX_URL, PIP_EXTRA_INDEX_URL
#                  where the builder's pip finds packages, when not PyPI (a mirror or proxy such
#                  as devpi or Artifactory). pip reads them from the environment; they exist in
#                  the builder stage only, not in the image. Credentials in them stay in the
#                  local build cache: prefer a netrc or an index without them.
ARG BASE=python:3.11-slim-bookworm

# --- builder: a virtual environment with gazehdr[daemon] -----------------------------------------
FROM ${BASE} AS builder

ARG PIP_INDEX_URL
ARG PIP_EXTRA_INDEX_URL

ENV PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PIP_ROOT_USER_ACTION=ignore
RUN python -m venv /opt/venv
ENV PATH=/opt/venv/bin:$PATH
WORKDIR /src

COPY pyproject.toml ./
RUN python -c "import tomllib; p = tomllib.load(open('pyproject.toml', 'rb'))['project']; print('\n'.join(p['dependencies'] + p['optional-dependencies']['daemon']))" > /tmp/requirements.txt \
    && pip install -r /tmp/requirements.txt

# The whole package is pure Python; the command line imports what each subcommand needs.
COPY README.md LICENSE MANIFEST.in ./
COPY server ./server
COPY drivers ./drivers
COPY web ./web
COPY docs ./docs
RUN pip install '.[daemon]'

# --- runtime -------------------------------------------------------------------------------------
FROM ${BASE} AS runtime

# The hidapi wheel bundles libudev and libusb: no system packages needed.
RUN (getent group plugdev || groupadd --system plugdev) \
    && groupadd --system --gid 10001 gazehdr \
    && useradd --system --uid 10001 --gid gazehdr --groups plugdev --create-home \
       --home-dir /home/gazehdr --shell /usr/sbin/nologin gazehdr \
    && mkdir -p /data \
    && chown gazehdr:gazehdr /data

COPY --from=builder /opt/venv /opt/venv

ENV PATH=/opt/venv/bin:$PATH \
    PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1 \
    GAZEHDR_RECORD_DIR=/data/recordings

WORKDIR /home/gazehdr
USER gazehdr
# Session logs: appended and flushed per record, so they survive the container.
VOLUME ["/data"]

ENTRYPOINT ["gazehdr", "daemon"]
CMD ["--source", "hid"]
