# Every dependency comes from a Debian 12 package (scripts/install-deps.sh).
find_package(Threads REQUIRED)
find_package(Boost 1.74 REQUIRED)
find_package(OpenSSL 3 REQUIRED)  # TLS (Boost.Asio ssl::stream), token comparison
find_package(Protobuf 3.21 REQUIRED)
find_package(embree 3 REQUIRED)
find_package(spdlog REQUIRED)
find_package(glm REQUIRED)
find_package(assimp REQUIRED)
find_package(CLI11 REQUIRED)
find_package(nlohmann_json 3 REQUIRED)
find_package(TBB REQUIRED)

find_package(OpenImageIO REQUIRED)
# Debian's OpenImageIO target lists /usr/include/opencv4, which does not exist
# without libopencv-dev, and CMake then refuses to generate. Drop that entry.
get_target_property(_oiio_includes OpenImageIO::OpenImageIO INTERFACE_INCLUDE_DIRECTORIES)
if(_oiio_includes)
  list(FILTER _oiio_includes EXCLUDE REGEX "opencv")
  set_target_properties(OpenImageIO::OpenImageIO PROPERTIES
    INTERFACE_INCLUDE_DIRECTORIES "${_oiio_includes}")
endif()

if(PENUMBRA_BUILD_TESTS)
  find_package(GTest REQUIRED)
endif()
if(PENUMBRA_BUILD_BENCH)
  find_package(benchmark REQUIRED)
endif()
if(PENUMBRA_BUILD_CLIENT_GUI)
  find_package(glfw3 3.3 REQUIRED)
  find_package(PkgConfig REQUIRED)
  pkg_check_modules(EPOXY REQUIRED IMPORTED_TARGET epoxy)
  # Dear ImGui for the HUD (Debian's libimgui-dev: a static library that
  # includes the GLFW and OpenGL 3 backends, so nothing is vendored).
  pkg_check_modules(IMGUI REQUIRED IMPORTED_TARGET imgui)
endif()
