# long3r_bench's profile (--profile-frames) on the tiny model: a printer's
# arithmetic, checked (python driver).
if(TARGET app_long3r_bench)
  add_test(NAME bench_profile
    COMMAND /usr/bin/python3 ${PROJECT_SOURCE_DIR}/test/model/bench_profile_test.py
      $<TARGET_FILE:app_long3r_bench>)
  set_tests_properties(bench_profile PROPERTIES
    ENVIRONMENT "OMP_NUM_THREADS=1;OPENBLAS_NUM_THREADS=1" TIMEOUT 120)
endif()
