# gazehdr server: the simulation (PyOpenCL on PoCL, the CPU), the FastAPI app and the web viewer.
#
#   docker build -f docker/server.Dockerfile -t gazehdr-server .          (from the repo root)
#   docker run --rm -p 127.0.0.1:8000:8000 -v gazehdr-data:/data gazehdr-server
#
# No GPU and no system OpenCL are needed: the pyopencl wheel bundles its ICD loader (ocl-icd)
# and the `pocl` extra brings PoCL with LLVM built in. PoCL links each compiled kernel into a
# shared object with the system's `ld` against libc and libgcc, so the runtime stage installs
# binutils, libc6-dev and libgcc-12-dev (without ld: "Executable "ld" doesn't exist!"; without
# the others: "ld: cannot find -lgcc ... -lc", "Final linking of kernel ... failed"; either way
# no frame is ever computed).
#
# GPU variant (NVIDIA; see docker/README.md and docker/compose.gpu.yaml): this same image. The
# bundled ICD loader also reads /etc/OpenCL/vendors, so run it with the NVIDIA Container Toolkit,
# which injects the driver's libnvidia-opencl.so.1 (driver capability `compute`), and give the
# loader the driver's ICD file, which older toolkits do not inject:
#
#   docker run --gpus all -e NVIDIA_DRIVER_CAPABILITIES=compute,utility \
#     -v /etc/OpenCL/vendors/nvidia.icd:/etc/OpenCL/vendors/nvidia.icd:ro \
#     -e GAZEHDR_CL_DEVICE=NVIDIA -p 127.0.0.1:8000:8000 gazehdr-server
#
# or bake the ICD file into a derived image:
#
#   FROM gazehdr-server
#   USER root
#   RUN mkdir -p /etc/OpenCL/vendors \
#       && echo libnvidia-opencl.so.1 > /etc/OpenCL/vendors/nvidia.icd
#   ENV NVIDIA_VISIBLE_DEVICES=all NVIDIA_DRIVER_CAPABILITIES=compute,utility
#   USER gazehdr
#
# An nvidia/cuda base adds nothing here: OpenCL needs only the driver library, which the toolkit
# mounts from the host, and not the CUDA runtime. The first GPU wins over PoCL; GAZEHDR_CL_DEVICE
# (a substring of the device name) makes a missing GPU an error instead of a quiet CPU fallback.

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

# --- builder: a virtual environment with gazehdr[server] -----------------------------------------
FROM ${BASE} AS builder

ARG PIP_INDEX_URL
ARG PIP_EXTRA_INDEX_URL

ENV PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    PIP_ROOT_USER_ACTION=ignore
RUN python -m venv /opt/venv
ENV PATH=/opt/venv/bin:$PATH
WORKDIR /src

# Dependencies first, from pyproject.toml alone, so that editing the code reuses this layer.
COPY pyproject.toml ./
RUN python -c "import tomllib; p = tomllib.load(open('pyproject.toml', 'rb'))['project']; print('\n'.join(p['dependencies'] + p['optional-dependencies']['server']))" > /tmp/requirements.txt \
    && pip install -r /tmp/requirements.txt

# Then the project itself, non-editable (kernels/*.cl, the viewer and docs/ travel as package
# data).
COPY README.md LICENSE MANIFEST.in ./
COPY server ./server
COPY drivers ./drivers
COPY web ./web
COPY docs ./docs
RUN pip install '.[server]'

# --- runtime -------------------------------------------------------------------------------------
FROM ${BASE} AS runtime

# What PoCL links each kernel with: `ld` (binutils) and -lc -lgcc -lgcc_s (libc6-dev,
# libgcc-12-dev). A base that has them (docker/make-base.sh) needs no Debian mirror here.
RUN dpkg -s binutils libc6-dev libgcc-12-dev >/dev/null 2>&1 || { apt-get update \
    && apt-get install -y --no-install-recommends binutils libc6-dev libgcc-12-dev \
    && rm -rf /var/lib/apt/lists/*; }

# /var/cache/pocl exists and is gazehdr's, so that a volume mounted there starts out writable.
RUN groupadd --system --gid 10001 gazehdr \
    && useradd --system --uid 10001 --gid gazehdr --create-home --home-dir /home/gazehdr \
       --shell /usr/sbin/nologin gazehdr \
    && mkdir -p /data /var/cache/pocl \
    && chown gazehdr:gazehdr /data /var/cache/pocl

COPY --from=builder /opt/venv /opt/venv

# GAZEHDR_TOKEN is read from the environment at run time when set (never baked into the image);
# otherwise the server generates one and prints it at start (`docker logs`).
# POCL_CACHE_DIR: PoCL's kernel cache (pyopencl leaves caching to PoCL). Built kernels make the
# first frame take a fraction of a second instead of seconds; compose keeps them on a volume.
ENV PATH=/opt/venv/bin:$PATH \
    PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1 \
    GAZEHDR_DATA_DIR=/data \
    POCL_CACHE_DIR=/var/cache/pocl

WORKDIR /app
USER gazehdr
# Session logs and uploaded scenes. (No VOLUME for the kernel cache: `docker run --rm` would
# throw an anonymous one away each time; name one, see docker/README.md.)
VOLUME ["/data"]
EXPOSE 8000

# No curl in slim images: the stdlib does it. An HTTP error or no answer raises, so exits 1.
HEALTHCHECK --interval=30s --timeout=5s --start-period=30s --retries=3 \
    CMD ["python", "-c", "import urllib.request; urllib.request.urlopen('http://127.0.0.1:8000/api/health', timeout=4).close()"]

# 0.0.0.0 inside the container; publish it on the host's loopback (see compose.yaml).
# --allow-host server: the compose file's daemon reaches it as ws://server:8000 (docs/security.md)
CMD ["gazehdr", "serve", "--host", "0.0.0.0", "--port", "8000", "--allow-host", "server"]
