# long3r_map_bench (the voxel map beside a PCL fusion): its table, checked on
# a few frames (python driver).
if(TARGET app_long3r_map_bench)
  add_test(NAME map_bench
    COMMAND /usr/bin/python3 ${PROJECT_SOURCE_DIR}/test/geometry/map_bench_test.py
      $<TARGET_FILE:app_long3r_map_bench>)
  set_tests_properties(map_bench PROPERTIES LABELS integration TIMEOUT 120)
endif()
