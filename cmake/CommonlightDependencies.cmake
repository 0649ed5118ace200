# Third-party dependencies. Required ones fail the configure step with a message naming the
# Debian package (scripts/install-deps installs them all); optional camera backends are left
# out with a message when their library is missing.

find_package(PkgConfig REQUIRED)
find_package(Threads REQUIRED)

macro(commonlight_require package debian)
  find_package(${package} ${ARGN} QUIET)
  if(NOT ${package}_FOUND)
    message(FATAL_ERROR "${package} not found: install the Debian package ${debian} (./scripts/install-deps)")
  endif()
endmacro()

commonlight_require(Eigen3 libeigen3-dev)
commonlight_require(OpenCV libopencv-dev COMPONENTS core imgproc imgcodecs videoio calib3d photo)
commonlight_require(yaml-cpp libyaml-cpp-dev)
commonlight_require(TinyGLTF libtinygltf-dev)
commonlight_require(tinyobjloader libtinyobjloader-dev)
commonlight_require(nlohmann_json nlohmann-json3-dev)
commonlight_require(CLI11 libcli11-dev)
commonlight_require(embree libembree-dev 3)
commonlight_require(TBB libtbb-dev)
commonlight_require(Ceres libceres-dev)
pkg_check_modules(TURBOJPEG REQUIRED IMPORTED_TARGET libturbojpeg)
pkg_check_modules(APRILTAG REQUIRED IMPORTED_TARGET apriltag)
if(COMMONLIGHT_BUILD_TESTS)
  commonlight_require(GTest libgtest-dev)
endif()
if(COMMONLIGHT_BUILD_BENCH)
  commonlight_require(benchmark libbenchmark-dev)
endif()

# yaml-cpp 0.7 in Debian 12 exports the target "yaml-cpp" without a namespace.
if(NOT TARGET yaml-cpp::yaml-cpp)
  add_library(yaml-cpp::yaml-cpp INTERFACE IMPORTED)
  target_link_libraries(yaml-cpp::yaml-cpp INTERFACE yaml-cpp)
endif()

# Optional camera backends.
# The V4L2 backend talks to the kernel API directly (linux/videodev2.h); libv4l2's pkg-config
# file stands for "the V4L2 development files are installed".
pkg_check_modules(V4L2 IMPORTED_TARGET libv4l2)
if(V4L2_FOUND AND EXISTS /usr/include/linux/videodev2.h)
  set(COMMONLIGHT_HAVE_V4L2 ON)
else()
  set(COMMONLIGHT_HAVE_V4L2 OFF)
  message(STATUS "V4L2 backend left out: libv4l2 / linux/videodev2.h not found (libv4l-dev, linux-libc-dev)")
endif()
pkg_check_modules(LIBCAMERA IMPORTED_TARGET libcamera)
if(LIBCAMERA_FOUND)
  set(COMMONLIGHT_HAVE_LIBCAMERA ON)
else()
  set(COMMONLIGHT_HAVE_LIBCAMERA OFF)
  message(STATUS "libcamera backend left out: libcamera not found (libcamera-dev)")
endif()
pkg_check_modules(ARAVIS IMPORTED_TARGET aravis-0.8)
if(ARAVIS_FOUND)
  set(COMMONLIGHT_HAVE_ARAVIS ON)
else()
  set(COMMONLIGHT_HAVE_ARAVIS OFF)
  message(STATUS "Aravis backend left out: aravis-0.8 not found (libaravis-dev, libusb-1.0-0-dev)")
endif()
