#!/usr/bin/env bash
# Build the reference FMU importers fmusim (Modelica Reference-FMUs) and
# fmuCheck (FMU Compliance Checker, FMI 1/2) offline, with Debian packages.
#
# Usage: build_importers.sh [SRC_REFERENCE_FMUS SRC_FMUCC SRC_FMIL [PREFIX]]
#   (or set the same names as environment variables; PREFIX defaults to ./importers)
# Sources are plain checkouts of github.com/modelica/Reference-FMUs,
# github.com/modelica-tools/FMUComplianceChecker and github.com/modelon-community/fmi-library.
# FMIL must be at tag 2.0.3 (the version the checker pins; FMIL 3.x does not build with it).
# Tested with Reference-FMUs b73e90b (v0.0.29-7), FMUComplianceChecker c704b98, FMIL 2.0.3.
# Needs: apt-get install -y cmake build-essential libxml2-dev zlib1g-dev libminizip-dev libsundials-dev
set -euo pipefail

SRC_REFERENCE_FMUS=$(realpath "${1:-${SRC_REFERENCE_FMUS:?}}")
SRC_FMUCC=$(realpath "${2:-${SRC_FMUCC:?}}")
SRC_FMIL=$(realpath "${3:-${SRC_FMIL:?}}")
PREFIX=$(realpath -m "${4:-${PREFIX:-importers}}")
BUILD=${BUILD_DIR:-$PREFIX/build}
JOBS=${JOBS:-$(nproc)}
# Debian's CMake 3.25: CMake >= 4 rejects FMIL 2.0.3 (reads the LOCATION target property, CMP0026).
CMAKE=${CMAKE:-/usr/bin/cmake}

rm -rf "$BUILD"
mkdir -p "$BUILD/src" "$PREFIX/bin"
# Patch copies, never the given source trees.
cp -a "$SRC_REFERENCE_FMUS" "$BUILD/src/reference-fmus"
cp -a "$SRC_FMUCC" "$BUILD/src/fmucc"

# fmusim: link the system libxml2, zlib, minizip and CVODE (6.4.1, as upstream uses)
# instead of the copies that build/build_*.py download and build.
patch -d "$BUILD/src/reference-fmus" -p1 <<'EOF'
--- a/fmusim/CMakeLists.txt
+++ b/fmusim/CMakeLists.txt
@@ -73,8 +73,6 @@
   fmusim_input.h
   fmusim_input.c
   miniunzip.c
-  ${ZLIB_SRC_DIR}/contrib/minizip/ioapi.c
-  ${ZLIB_SRC_DIR}/contrib/minizip/unzip.c
   ../src/structured_variable_name.yy.c
   ../include/structured_variable_name.tab.h
   ../src/structured_variable_name.tab.c
@@ -86,6 +84,20 @@
 
 add_executable(fmusim ${sources})
 
+# use the system (Debian) libraries instead of the ones build/build_*.py would download
+if (TRUE)
+  find_package(LibXml2 REQUIRED)
+  find_package(ZLIB REQUIRED)
+  find_path(MINIZIP_INCLUDE_DIR unzip.h PATH_SUFFIXES minizip REQUIRED)
+  find_library(MINIZIP_LIBRARY minizip REQUIRED)
+  find_path(CVODE_INCLUDE_DIR cvode/cvode.h REQUIRED)
+  find_library(CVODE_LIBRARY sundials_cvode REQUIRED)
+  target_include_directories(fmusim PRIVATE . ../include ${MINIZIP_INCLUDE_DIR} ${CVODE_INCLUDE_DIR})
+  target_link_libraries(fmusim LibXml2::LibXml2 ${MINIZIP_LIBRARY} ZLIB::ZLIB ${CVODE_LIBRARY} ${CMAKE_DL_LIBS} m)
+  install(TARGETS fmusim DESTINATION bin)
+  return()
+endif ()
+
 target_include_directories(fmusim PRIVATE
   .
   ../include
EOF
# fmusim bug (still in v0.0.38): FMIUtil.c passes the FMU state itself instead of its address to
# fmi2FreeFMUstate/fmi3FreeFMUState, so --initial/--final-fmu-state-file crash in the FMU.
sed -i -E 's/(FMI(2FreeFMUstate|3FreeFMUState)\(S, )FMUState\)/\1\&FMUState)/' "$BUILD/src/reference-fmus/fmusim/FMIUtil.c"
[[ $(grep -c 'FreeFMU[Ss]tate(S, &FMUState)' "$BUILD/src/reference-fmus/fmusim/FMIUtil.c") == 4 ]]
"$CMAKE" -S "$BUILD/src/reference-fmus/fmusim" -B "$BUILD/fmusim" -DCMAKE_BUILD_TYPE=Release -DCMAKE_INSTALL_PREFIX="$PREFIX"
"$CMAKE" --build "$BUILD/fmusim" -j "$JOBS"
"$CMAKE" --install "$BUILD/fmusim"

# fmuCheck: its CMakeLists git-clones FMIL 2.0.3 into <src>/FMIL; build the local FMIL
# source through the same ExternalProject instead (the file has CRLF line ends, hence sed).
sed -i -e 's|^set(FMUCHK_FMIL_HOME_DIR "${FMUCHK_HOME}/FMIL")|set(FMUCHK_FMIL_HOME_DIR "" CACHE PATH "FMIL source")|' \
       -e 's|^\tGIT_REPOSITORY .*fmi-library.git"|\tDOWNLOAD_COMMAND ""|' \
       -e '/^\tGIT_TAG 2.0.3/d' "$BUILD/src/fmucc/CMakeLists.txt"
grep -q 'DOWNLOAD_COMMAND ""' "$BUILD/src/fmucc/CMakeLists.txt"
"$CMAKE" -S "$BUILD/src/fmucc" -B "$BUILD/fmucc" -DCMAKE_BUILD_TYPE=Release \
    -DFMUCHK_FMIL_HOME_DIR="$SRC_FMIL" -DFMUCHK_INSTALL_PREFIX="$PREFIX/bin"
"$CMAKE" --build "$BUILD/fmucc" -j "$JOBS"
"$CMAKE" --install "$BUILD/fmucc"

echo "fmusim:   $PREFIX/bin/fmusim"
echo "fmuCheck: $PREFIX/bin/fmuCheck.$(sed -n 's/^FMUCHK_FMI_PLATFORM:STRING=//p' "$BUILD/fmucc/CMakeCache.txt")"
