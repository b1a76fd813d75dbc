# The libFuzzer target test/fuzz/fuzz_safetensors_header.cpp, driven by a
# plain main() that replays the seed corpus plus seeded random mutations of it,
# so the same entry point runs under any compiler as an ordinary test.
# (The real libFuzzer build is cmake/Long3rFuzzers.cmake, clang only.)
add_executable(long3r_fuzz_replay
  ${PROJECT_SOURCE_DIR}/test/fuzz/replay_main.cpp
  ${PROJECT_SOURCE_DIR}/test/fuzz/fuzz_safetensors_header.cpp)
target_link_libraries(long3r_fuzz_replay PRIVATE long3r_io)
target_compile_options(long3r_fuzz_replay PRIVATE ${LONG3R_WARNINGS})
add_test(NAME fuzz_safetensors_header_replay
  COMMAND long3r_fuzz_replay ${PROJECT_SOURCE_DIR}/test/data/fuzz_corpus 5000 1
  WORKING_DIRECTORY ${PROJECT_BINARY_DIR})
