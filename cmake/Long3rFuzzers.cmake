# libFuzzer targets (clang only). Configure a separate build folder:
#   CC=clang CXX=clang++ cmake -S . -B build-fuzz -DLONG3R_WITH_ROS=OFF -DLONG3R_BUILD_FUZZERS=ON
#   cmake --build build-fuzz --target fuzz_safetensors_header
#   build-fuzz/fuzz_safetensors_header -max_total_time=60 test/data/fuzz_corpus
# The same fuzz entry point also runs under gcc as a corpus-replay ctest
# (test/fuzz/fuzz.cmake), so CI exercises it without clang.
if(NOT CMAKE_CXX_COMPILER_ID MATCHES "Clang")
  message(FATAL_ERROR "LONG3R_BUILD_FUZZERS needs clang (CC=clang CXX=clang++)")
endif()
set(LONG3R_FUZZ_FLAGS -fsanitize=fuzzer,address,undefined -fno-sanitize-recover=undefined -g -O1)
add_executable(fuzz_safetensors_header
  test/fuzz/fuzz_safetensors_header.cpp
  $<TARGET_PROPERTY:long3r_io,SOURCES>)
target_include_directories(fuzz_safetensors_header PRIVATE ${PROJECT_SOURCE_DIR}/include)
target_link_libraries(fuzz_safetensors_header PRIVATE nlohmann_json::nlohmann_json)
target_compile_options(fuzz_safetensors_header PRIVATE ${LONG3R_FUZZ_FLAGS})
target_link_options(fuzz_safetensors_header PRIVATE ${LONG3R_FUZZ_FLAGS})
