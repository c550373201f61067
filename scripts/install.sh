#!/usr/bin/env bash
# Install sheaf for C and C++ users under PREFIX (the layout of cargo-c):
#
#   PREFIX/include/sheaf/sheaf.h, sheaf.hpp
#   PREFIX/lib/libsheaf.a
#   PREFIX/lib/libsheaf.so.X.Y.Z, libsheaf.so.X -> it (the soname), libsheaf.so -> libsheaf.so.X
#   PREFIX/lib/pkgconfig/sheaf.pc, sheaf-static.pc
#   PREFIX/lib/cmake/sheaf/sheafConfig.cmake, sheafConfigVersion.cmake
#
# Usage:
#   scripts/install.sh PREFIX            # cargo build --release --lib, then install
#   SHEAF_LIB_DIR=DIR scripts/install.sh PREFIX
#                                        # install libsheaf.a and libsheaf.so from DIR, no build
#   DESTDIR=/tmp/stage scripts/install.sh /usr/local
#                                        # staged install (packagers): files under DESTDIR, paths say PREFIX
#
# The templates are in pkg/. Libs.private and the static CMake target's
# INTERFACE_LINK_LIBRARIES are the system libraries Rust's std needs, as
# `rustc --print native-static-libs` reports them for this toolchain (sheaf
# itself links no native library).
set -euo pipefail

if [ $# -ne 1 ] || [ -z "$1" ]; then
  echo "usage: $0 PREFIX   (SHEAF_LIB_DIR=dir to install prebuilt libraries, DESTDIR to stage)" >&2
  exit 2
fi
root="$(cd "$(dirname "$0")/.." && pwd)"
case "$1" in
  /*) prefix="$1" ;;
  *) prefix="$(pwd)/$1" ;;
esac
prefix="${prefix%/}"
dest="${DESTDIR:-}${prefix}"

# The version from Cargo.toml's [package] (the first `version = "..."` line).
version="$(sed -n 's/^version *= *"\([0-9][0-9.]*\)".*/\1/p' "$root/Cargo.toml" | head -n 1)"
case "$version" in
  *.*.*) ;;
  *) echo "cannot read the package version from $root/Cargo.toml" >&2; exit 1 ;;
esac
major="${version%%.*}"
# The soname's version (pkg/README.md): MAJOR, or 0.MINOR while MAJOR is 0
# (cargo-c's rule: a 0.x minor release may break the ABI).
minor="${version#*.}"; minor="${minor%%.*}"
if [ "$major.$minor" = 0.0 ]; then sover="0.0.${version##*.}"
elif [ "$major" = 0 ]; then sover="0.$minor"; else sover="$major"; fi
rest="${version#*.}"
minor="${rest%%.*}"

if [ -n "${SHEAF_LIB_DIR:-}" ]; then
  libdir_in="$SHEAF_LIB_DIR"
else
  echo "== cargo build --release --lib"
  (cd "$root" && cargo build --release --lib)
  libdir_in="${CARGO_TARGET_DIR:-$root/target}/release"
fi
for f in libsheaf.a libsheaf.so; do
  [ -f "$libdir_in/$f" ] || { echo "$libdir_in/$f is missing" >&2; exit 1; }
done

# The system libraries a static link needs: ask rustc for those of an empty
# std staticlib (what sheaf's libsheaf.a needs too: it has no -sys crates).
probe="$(mktemp -d)"
trap 'rm -rf "$probe"' EXIT
printf 'pub fn probe() {}\n' > "$probe/probe.rs"
native="$("${RUSTC:-rustc}" --edition 2021 --crate-type staticlib --crate-name sheafprobe \
  --print native-static-libs -o "$probe/libsheafprobe.a" "$probe/probe.rs" 2>&1 |
  sed -n 's/.*native-static-libs: *//p' | head -n 1)"
if [ -z "$native" ]; then
  native="-lgcc_s -lutil -lrt -lpthread -lm -ldl -lc"
  echo "warning: rustc did not report native-static-libs; using: $native" >&2
fi
# CMake wants a list of names: -lm -> m.
cmake_native="$(printf '%s\n' $native | sed -n 's/^-l//p' | paste -sd ';' -)"

echo "== installing sheaf $version into ${dest}"
install -d "$dest/include/sheaf" "$dest/lib/pkgconfig" "$dest/lib/cmake/sheaf"
install -m 644 "$root/include/sheaf.h" "$dest/include/sheaf/sheaf.h"
install -m 644 "$root/include/sheaf.hpp" "$dest/include/sheaf/sheaf.hpp"
install -m 644 "$libdir_in/libsheaf.a" "$dest/lib/libsheaf.a"
install -m 755 "$libdir_in/libsheaf.so" "$dest/lib/libsheaf.so.$version"
ln -sfn "libsheaf.so.$version" "$dest/lib/libsheaf.so.$sover"
ln -sfn "libsheaf.so.$sover" "$dest/lib/libsheaf.so"

subst() {
  sed -e "s|@PREFIX@|$prefix|g" -e "s|@VERSION@|$version|g" -e "s|@MAJOR@|$major|g" \
    -e "s|@MINOR@|$minor|g" -e "s|@NATIVE_LIBS@|$native|g" \
    -e "s|@CMAKE_NATIVE_LIBS@|$cmake_native|g" "$1" > "$2"
  chmod 644 "$2"
}
subst "$root/pkg/sheaf.pc.in" "$dest/lib/pkgconfig/sheaf.pc"
subst "$root/pkg/sheaf-static.pc.in" "$dest/lib/pkgconfig/sheaf-static.pc"
subst "$root/pkg/sheafConfig.cmake.in" "$dest/lib/cmake/sheaf/sheafConfig.cmake"
subst "$root/pkg/sheafConfigVersion.cmake.in" "$dest/lib/cmake/sheaf/sheafConfigVersion.cmake"

if command -v readelf >/dev/null 2>&1; then
  soname="$(readelf -d "$dest/lib/libsheaf.so.$version" | sed -n 's/.*Library soname: \[\(.*\)\].*/\1/p')"
  if [ "$soname" != "libsheaf.so.$sover" ]; then
    echo "warning: libsheaf.so has soname '${soname:-none}', expected libsheaf.so.$sover (build.rs sets it on Linux)" >&2
  fi
fi
echo "installed: include/sheaf/sheaf.h, sheaf.hpp, lib/libsheaf.{a,so.$version,so.$sover,so}, lib/pkgconfig/sheaf{,-static}.pc, lib/cmake/sheaf/"
echo "use: PKG_CONFIG_PATH=$prefix/lib/pkgconfig pkg-config --cflags --libs sheaf"
echo "     cmake -DCMAKE_PREFIX_PATH=$prefix ...   (find_package(sheaf CONFIG REQUIRED))"
