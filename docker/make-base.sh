#!/bin/sh
# Makes a Debian bookworm base image for docker/*.Dockerfile from Debian's packages, for hosts
# that reach a Debian mirror but no image registry (python:3.11-slim-bookworm cannot be pulled):
#
#   sudo docker/make-base.sh      # prints the tag, e.g. gazehdr-base:bookworm-1a2b3c4d5e6f
#   docker build --build-arg BASE=gazehdr-base:bookworm-1a2b3c4d5e6f \
#     -f docker/server.Dockerfile -t gazehdr-server .
#
# Needs root, mmdebstrap (apt-get install mmdebstrap) and a Docker engine; about a minute and a
# half. The image offers what the Dockerfiles use from python:3.11-slim-bookworm: `python`
# (Debian's python3, 3.11) with venv and pip (ensurepip's wheel), useradd/groupadd and apt; and
# what PoCL links each kernel with: `ld` (binutils) and libc and libgcc to link against
# (libc6-dev, libgcc-12-dev), so that the server's runtime stage skips its apt-get step and its
# build needs no Debian mirror either (the daemon image carries these 60 MB unused). The wheels
# gazehdr installs (pyopencl with its ICD loader, PoCL with LLVM, OpenEXR,
# opencv-python-headless, Pillow, hidapi) bundle their other libraries.
#
# Options (environment variables):
#   MIRROR     a Debian mirror's URI, for bookworm and bookworm-updates; with it, SECURITY_MIRROR
#              for bookworm-security (without it, no security updates). Both unset: mmdebstrap's
#              defaults, Debian's own mirrors for all three. They are the image's sources.list.
#   CA_CERTS   space-separated PEM files added to the image's trust store (update-ca-certificates),
#              for networks whose HTTPS goes through an intercepting proxy: the builder stage's
#              pip (Debian's) verifies PyPI, or PIP_INDEX_URL, against the system store. They stay
#              in the images built on this base.
#   TAG        the image's name. Default: gazehdr-base:bookworm-KEY, KEY the first 12 hex digits
#              of a sha256 over this script, the mirrors and the CA files, so that a change to any
#              of them makes a new base and an unchanged one can be reused.
#   REUSE=1    print the tag and exit if an image with that tag exists already (without it, the
#              base is made anew from the mirror's current packages and takes the tag over).
#
# Prints the tag on stdout, and everything else on stderr.
set -eu

here=$(cd "$(dirname "$0")" && pwd)
MIRROR=${MIRROR:-}
SECURITY_MIRROR=${SECURITY_MIRROR:-}
CA_CERTS=${CA_CERTS:-}
if [ -n "$SECURITY_MIRROR" ] && [ -z "$MIRROR" ]; then
    echo "make-base.sh: SECURITY_MIRROR needs MIRROR" >&2
    exit 2
fi
for cert in $CA_CERTS; do
    [ -r "$cert" ] || { echo "make-base.sh: cannot read CA certificate $cert" >&2; exit 2; }
done
key=$({ cat "$here/make-base.sh"; echo "$MIRROR $SECURITY_MIRROR"; for cert in $CA_CERTS; do
    cat "$cert"; done; } | sha256sum | cut -c1-12)
TAG=${TAG:-gazehdr-base:bookworm-$key}

if [ "${REUSE:-0}" = 1 ] && docker image inspect "$TAG" >/dev/null 2>&1; then
    echo "$TAG"
    exit 0
fi

work=$(mktemp -d)
trap 'rm -rf "$work"' EXIT
mkdir "$work/ca"
for cert in $CA_CERTS; do
    cp "$cert" "$work/ca/$(basename "$cert" .crt | tr -c 'A-Za-z0-9_.\n-' _).crt"
done

# mmdebstrap's MIRROR arguments: none for its defaults.
set --
if [ -n "$MIRROR" ]; then
    set -- "deb $MIRROR bookworm main" "deb $MIRROR bookworm-updates main"
fi
if [ -n "$SECURITY_MIRROR" ]; then
    set -- "$@" "deb $SECURITY_MIRROR bookworm-security main"
fi

# minbase: Essential packages and apt. The merged-usr hook makes the merged /usr layout itself,
# instead of installing usrmerge, which would bring the whole of perl (50 MB). Docs, man pages
# and translations are left out (the copyright files stay), as in Debian's slim images. The hooks'
# "$1" is the new root, expanded by mmdebstrap's shell, not this one.
# shellcheck disable=SC2016
mmdebstrap \
    --variant=minbase \
    --hook-dir=/usr/share/mmdebstrap/hooks/merged-usr \
    --include=python3,python3-venv,python-is-python3,ca-certificates,passwd \
    --include=binutils,libc6-dev,libgcc-12-dev \
    --dpkgopt='path-exclude=/usr/share/man/*' \
    --dpkgopt='path-exclude=/usr/share/info/*' \
    --dpkgopt='path-exclude=/usr/share/locale/*' \
    --dpkgopt='path-include=/usr/share/locale/locale.alias' \
    --dpkgopt='path-exclude=/usr/share/doc/*' \
    --dpkgopt='path-include=/usr/share/doc/*/copyright' \
    --customize-hook="sync-in $work/ca /usr/local/share/ca-certificates" \
    --customize-hook='chroot "$1" update-ca-certificates --fresh >/dev/null' \
    --customize-hook='rm -rf "$1"/var/cache/apt/*.bin "$1"/var/log/apt/*' \
    --customize-hook='rm -f "$1"/var/log/dpkg.log "$1"/var/log/alternatives.log' \
    --customize-hook='rm -f "$1"/etc/machine-id "$1"/var/lib/dbus/machine-id' \
    bookworm "$work/rootfs.tar" "$@" >&2

docker import \
    --change 'ENV LANG=C.UTF-8' \
    --change 'ENV PATH=/usr/local/sbin:/usr/local/bin:/usr/sbin:/usr/bin:/sbin:/bin' \
    --change 'CMD ["python3"]' \
    --message "docker/make-base.sh $key: Debian bookworm (mmdebstrap minbase), python3" \
    "$work/rootfs.tar" "$TAG" >&2
echo "$TAG"
