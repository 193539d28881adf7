# gazehdr server: the simulation (PyOpenCL on PoCL, the CPU), the FastAPI app and the web viewer.
#
#   docker build -f docker/server.Dockerfile -t gazehdr-server .          (from the repo root)
#   docker run --rm -p 127.0.0.1:8000:8000 -v gazehdr-data:/data gazehdr-server
#
# No GPU and no system OpenCL are needed: the pyopencl wheel bundles its ICD loader (ocl-icd)
# and the `pocl` extra brings PoCL with LLVM built in. PoCL links each compiled kernel with the
# system `ld`, so the runtime stage installs binutils (without it: "Executable "ld" doesn't
# exist!" and an abort at the first kernel build).
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

# --- builder: a virtual environment with gazehdr[server] -----------------------------------------
FROM python:3.11-slim-bookworm AS builder

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

# Then the project itself, non-editable (kernels/*.cl and the viewer travel as package data).
COPY README.md LICENSE ./
COPY server ./server
COPY drivers ./drivers
COPY web ./web
RUN pip install '.[server]'

# --- runtime -------------------------------------------------------------------------------------
FROM python:3.11-slim-bookworm AS runtime

RUN apt-get update \
    && apt-get install -y --no-install-recommends binutils \
    && rm -rf /var/lib/apt/lists/*

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
