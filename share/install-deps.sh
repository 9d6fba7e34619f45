#!/usr/bin/env bash
# Installs everything tinbuild needs to build and test on Debian 12, from Debian packages only.
# Idempotent: when every package is already installed it changes nothing and returns quickly.
set -euo pipefail
packages=(
  build-essential cmake g++ git
  libgdal-dev gdal-bin          # GDAL: GeoTIFF, GeoPackage, OGR; gdalinfo/ogrinfo for tests
  libproj-dev proj-bin          # PROJ: CRS and transformations; projinfo/cs2cs for tests
  libgeographiclib-dev          # GeographicLib: UTM/UPS zones, geodesic areas
  libnetcdf-dev pkg-config      # NetCDF-4: the UGRID mesh writer (--mesh FILE.nc)
  libsqlite3-dev                # SQLite with R*Tree: the GeoPackage TIN writer writes its file directly
  libopenmpi-dev openmpi-bin    # Open MPI: `build --mpi` under mpirun (optional at build time; tests use it)
  libgtest-dev libgmock-dev     # GoogleTest (tests only)
  libcgal-dev libgmp-dev        # CGAL (tests and benchmarks only: independent oracle and speed peer)
  clang libclang-rt-14-dev      # clang and libFuzzer: the bounded fuzz run of the LAZ reader (tests/fuzz)
  python3-qgis                  # QGIS 3.22's Python bindings with Processing, GDAL/OGR/MDAL providers and Qt's
                                # offscreen platform: the headless QGIS tests (tests/qgis) and the provider
  python3-vtk9                  # VTK's Python bindings: the .vtu written by `tetrahedralize` read back by
                                # vtkXMLUnstructuredGridReader (tests/formats/mesh/check_vtu.py)
  fonts-dejavu-core             # a font for QGIS's widgets and maps rendered offscreen (share/qgis screenshots)
)
missing=()
for p in "${packages[@]}"; do
  dpkg-query -W -f='${Status}' "$p" 2>/dev/null | grep -q "install ok installed" || missing+=("$p")
done
if [ ${#missing[@]} -eq 0 ]; then
  echo "install-deps: all ${#packages[@]} packages present"
  exit 0
fi
SUDO=""
if [ "$(id -u)" -ne 0 ]; then SUDO="sudo"; fi
echo "install-deps: installing ${missing[*]}"
$SUDO apt-get update -qq
DEBIAN_FRONTEND=noninteractive $SUDO apt-get install -y -qq --no-install-recommends "${missing[@]}" >/dev/null
echo "install-deps: done"
