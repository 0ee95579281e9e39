#!/usr/bin/env bash
# Installs every Debian 12 package hybrid-octree needs to build, test and run its demo; with --mpi,
# also what the MPI build (-DHYB_MPI=ON) needs. Idempotent: apt-get skips what is already installed.
# Run as root (or with sudo).
set -euo pipefail
packages=(
  build-essential cmake ninja-build pkg-config   # toolchain
  libglm-dev                                     # vector maths shared by every module
  zlib1g-dev libarchive-dev                      # gzip NRRD/MetaImage data; InVesalius .inv3 (tar.gz)
  libzstd-dev                                    # the scene file's compressed knot store
  libnifti2-dev                                  # NIfTI-1/2 reader (nifti_clib), .nii and .nii.gz
  libgdcm-dev                                    # DICOM series: parsing, decompression, rescale tags
  libcurl4-openssl-dev                           # DICOMweb (PACS): HTTP with TLS, timeouts, redirects, authentication
  orthanc orthanc-dicomweb                       # the DICOMweb archive the tests and bench/dicomweb_bench.sh upload series to
  libcli11-dev                                   # command-line parsing with subcommands
  nlohmann-json3-dev                             # JSON: --stats, camera files, the viewer's messages
  libboost-dev libturbojpeg0-dev                 # the viewer's server: Boost.Beast (HTTP, WebSocket); JPEG frames
  libpng-dev                                     # PNG output
  libcgal-dev libopenmesh-dev                    # exact mesh checks; mesh storage and IO
  libmeshoptimizer-dev                           # the simplified isosurface drawn while the view moves
  libembree-dev                                  # the reference ray tracer's ray–triangle queries (Embree's BVH)
  libosmesa6-dev                                 # off-screen OpenGL 4.5 core through llvmpipe
  pybind11-dev python3-dev python3-numpy         # the Python module (numpy arrays in, images and meshes out)
  python3-pytest                                 # its tests
  libgtest-dev libbenchmark-dev                  # tests and micro-benchmarks
  clang-14 libfuzzer-14-dev                      # the fuzz targets (tests/fuzz) and their regression run
  gnuplot-nox                                    # the plot of `hybrid-octree bench` (speed/accuracy trade)
  invesalius-examples                            # the real CT used by the demo and the tests
  chromium                                       # the viewer's end-to-end test drives the page in it
)
if [ "${1:-}" = "--mpi" ]; then
  packages+=(
    libopenmpi-dev openmpi-bin                   # MPI ranks (mpirun)
    paraview-dev                                 # IceT, the ranks' ordered compositing (Debian has it only in ParaView)
  )
fi
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if ((${#missing[@]})); then
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  $SUDO apt-get update -qq
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}"
fi

# Node.js and npm for the end-to-end test (Debian's, unless a node with npm is there already), and
# puppeteer-core at the version the lock file pins.
if ! command -v node > /dev/null || ! command -v npm > /dev/null; then
  SUDO=""; [ "$(id -u)" -eq 0 ] || SUDO="sudo"
  DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends nodejs npm
fi
here="$(cd "$(dirname "$0")/.." && pwd)"
if [ ! -d "$here/tests/e2e/node_modules/puppeteer-core" ]; then
  npm ci --prefix "$here/tests/e2e" --no-audit --no-fund --loglevel=error > /dev/null
fi
