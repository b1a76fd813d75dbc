# Golden parity: one ctest per case folder of ../shared/golden (official
# DUSt3R / Spann3R reference runs). The folder is globbed at configure time
# (CONFIGURE_DEPENDS re-globs on build), so new cases are picked up without
# editing this file. long3r_golden compares every stored tensor at 1e-4
# relative and fails on any tensor it did not compare.
if(TARGET app_long3r_golden)
  file(GLOB LONG3R_GOLDEN_CASE_DIRS LIST_DIRECTORIES true CONFIGURE_DEPENDS
       "${LONG3R_SHARED_DIR}/golden/*")
  foreach(case_dir ${LONG3R_GOLDEN_CASE_DIRS})
    if(IS_DIRECTORY "${case_dir}" AND EXISTS "${case_dir}/io.safetensors"
       AND EXISTS "${case_dir}/weights.safetensors")
      get_filename_component(case "${case_dir}" NAME)
      add_test(NAME golden_${case}
               COMMAND app_long3r_golden ${LONG3R_SHARED_DIR}/golden/${case})
      # One thread: the runs are small, and spinning OpenMP workers on a
      # loaded machine cost far more than they bring.
      set_tests_properties(golden_${case} PROPERTIES
        TIMEOUT 600 LABELS golden
        ENVIRONMENT "OMP_NUM_THREADS=1;OPENBLAS_NUM_THREADS=1")
    endif()
  endforeach()
endif()
