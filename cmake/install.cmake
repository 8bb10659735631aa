# Installs the built C library into a prefix, with its headers, a pkg-config file and a CMake
# package config (target lacuna::lacuna, shared; lacuna::lacuna_static, static):
#
#   cargo build --release
#   cmake -DLACUNA_LIB_DIR=target/release -DPREFIX=/usr/local -P cmake/install.cmake
#
# Layout: PREFIX/include/{lacuna.h,lacuna.hpp}, PREFIX/lib/liblacuna.so.X.Y.Z (the SONAME),
# liblacuna.so -> it, liblacuna.a, PREFIX/lib/pkgconfig/{lacuna,lacuna-static}.pc,
# PREFIX/lib/cmake/lacuna/lacuna{Config,ConfigVersion}.cmake.
cmake_minimum_required(VERSION 3.16)
get_filename_component(SRC "${CMAKE_CURRENT_LIST_DIR}/.." ABSOLUTE)
if(NOT DEFINED LACUNA_LIB_DIR)
  set(LACUNA_LIB_DIR "${SRC}/target/release")
endif()
if(NOT DEFINED PREFIX)
  message(FATAL_ERROR "give -DPREFIX=<install prefix>")
endif()
get_filename_component(LACUNA_LIB_DIR "${LACUNA_LIB_DIR}" ABSOLUTE BASE_DIR "${SRC}")
get_filename_component(PREFIX "${PREFIX}" ABSOLUTE BASE_DIR "${SRC}")

# The version, from Cargo.toml.
file(STRINGS "${SRC}/Cargo.toml" version_line REGEX "^version = \"[0-9]+\\.[0-9]+\\.[0-9]+\"" LIMIT_COUNT 1)
string(REGEX REPLACE "^version = \"([0-9.]+)\"" "\\1" LACUNA_VERSION "${version_line}")
if(NOT LACUNA_VERSION)
  message(FATAL_ERROR "no version in ${SRC}/Cargo.toml")
endif()

foreach(f liblacuna.so liblacuna.a)
  if(NOT EXISTS "${LACUNA_LIB_DIR}/${f}")
    message(FATAL_ERROR "${LACUNA_LIB_DIR}/${f} is missing: run cargo build --release first")
  endif()
endforeach()

file(MAKE_DIRECTORY "${PREFIX}/include" "${PREFIX}/lib/pkgconfig" "${PREFIX}/lib/cmake/lacuna")
file(COPY "${SRC}/include/lacuna.h" "${SRC}/bindings/cpp/lacuna.hpp" DESTINATION "${PREFIX}/include")
file(COPY_FILE "${LACUNA_LIB_DIR}/liblacuna.so" "${PREFIX}/lib/liblacuna.so.${LACUNA_VERSION}")
file(COPY_FILE "${LACUNA_LIB_DIR}/liblacuna.a" "${PREFIX}/lib/liblacuna.a")
file(REMOVE "${PREFIX}/lib/liblacuna.so")
file(CREATE_LINK "liblacuna.so.${LACUNA_VERSION}" "${PREFIX}/lib/liblacuna.so" SYMBOLIC)

configure_file("${SRC}/lacuna.pc.in" "${PREFIX}/lib/pkgconfig/lacuna.pc" @ONLY)
configure_file("${SRC}/cmake/lacuna-static.pc.in" "${PREFIX}/lib/pkgconfig/lacuna-static.pc" @ONLY)
configure_file("${SRC}/cmake/lacunaConfig.cmake.in" "${PREFIX}/lib/cmake/lacuna/lacunaConfig.cmake" @ONLY)
include(CMakePackageConfigHelpers)
# While 0.x every release may break the ABI: only the exact version is compatible.
write_basic_package_version_file("${PREFIX}/lib/cmake/lacuna/lacunaConfigVersion.cmake"
  VERSION "${LACUNA_VERSION}" COMPATIBILITY ExactVersion)
message(STATUS "installed lacuna ${LACUNA_VERSION} into ${PREFIX}")
