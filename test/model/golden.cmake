# Golden parity: one ctest per case folder of test/data/golden (official
# DUSt3R / Spann3R reference runs). The folder is globbed at configure time
# (CONFIGURE_DEPENDS re-globs on build), so new cases are picked up without
# editing this file. long3r_golden compares every stored tensor at 1e-4
# relative and fails on any tensor it did not compare.
#
# golden_bf16_<case>: the same case in bfloat16 (emulated where the CPU has no
# native bfloat16), its outputs bounded at the deviation measured on the
# development machine plus about 50 % (docs/performance.md, "Precision"):
#   dust3r_pair_land112x80 2.34e-2, dust3r_pair_port80x112 1.97e-2,
#   dust3r_pair_sq224 8.91e-2, spann3r_seq_land96x64 1.72e-2,
#   spann3r_seq_sq224 6.68e-2 (max relative deviation of any output).
set(LONG3R_GOLDEN_BF16_TOL_dust3r_pair_land112x80 0.035)
set(LONG3R_GOLDEN_BF16_TOL_dust3r_pair_port80x112 0.03)
set(LONG3R_GOLDEN_BF16_TOL_dust3r_pair_sq224 0.135)
set(LONG3R_GOLDEN_BF16_TOL_spann3r_seq_land96x64 0.026)
set(LONG3R_GOLDEN_BF16_TOL_spann3r_seq_sq224 0.10)
#
# golden_bf16conv_<case>: bfloat16 with the convolutions in bfloat16 too
# (conv_precision auto), the path of CPUs with native bfloat16 only (skipped
# elsewhere: emulated bfloat16 convolutions lose 5 %, so auto keeps them
# float32 there, which golden_bf16 covers). Bounds: the deviation measured on
# an AMD EPYC with AVX512-BF16 plus about 50 %:
#   dust3r_pair_land112x80 3.00e-2, dust3r_pair_port80x112 3.50e-2,
#   dust3r_pair_sq224 4.36e-2, spann3r_seq_land96x64 6.27e-2,
#   spann3r_seq_sq224 3.51e-2.
set(LONG3R_GOLDEN_BF16CONV_TOL_dust3r_pair_land112x80 0.045)
set(LONG3R_GOLDEN_BF16CONV_TOL_dust3r_pair_port80x112 0.053)
set(LONG3R_GOLDEN_BF16CONV_TOL_dust3r_pair_sq224 0.065)
set(LONG3R_GOLDEN_BF16CONV_TOL_spann3r_seq_land96x64 0.094)
set(LONG3R_GOLDEN_BF16CONV_TOL_spann3r_seq_sq224 0.053)
if(TARGET app_long3r_golden)
  file(GLOB LONG3R_GOLDEN_CASE_DIRS LIST_DIRECTORIES true CONFIGURE_DEPENDS
       "${LONG3R_GOLDEN_DIR}/*")
  foreach(case_dir ${LONG3R_GOLDEN_CASE_DIRS})
    if(IS_DIRECTORY "${case_dir}" AND EXISTS "${case_dir}/io.safetensors"
       AND EXISTS "${case_dir}/weights.safetensors")
      get_filename_component(case "${case_dir}" NAME)
      add_test(NAME golden_${case}
               COMMAND app_long3r_golden ${case_dir})
      # One thread: the runs are small, and spinning OpenMP workers on a
      # loaded machine cost far more than they bring.
      set_tests_properties(golden_${case} PROPERTIES
        TIMEOUT 600 LABELS golden
        ENVIRONMENT "OMP_NUM_THREADS=1;OPENBLAS_NUM_THREADS=1")
      if(DEFINED LONG3R_GOLDEN_BF16_TOL_${case})
        add_test(NAME golden_bf16_${case}
                 COMMAND app_long3r_golden --precision bfloat16 --allow-emulated-precision
                         --conv-precision float32
                         --tol ${LONG3R_GOLDEN_BF16_TOL_${case}} ${case_dir})
        set_tests_properties(golden_bf16_${case} PROPERTIES
          TIMEOUT 600 LABELS golden
          ENVIRONMENT "OMP_NUM_THREADS=1;OPENBLAS_NUM_THREADS=1")
      endif()
      if(DEFINED LONG3R_GOLDEN_BF16CONV_TOL_${case})
        add_test(NAME golden_bf16conv_${case}
                 COMMAND app_long3r_golden --precision bfloat16 --conv-precision auto
                         --skip-unsupported
                         --tol ${LONG3R_GOLDEN_BF16CONV_TOL_${case}} ${case_dir})
        set_tests_properties(golden_bf16conv_${case} PROPERTIES
          TIMEOUT 600 LABELS golden SKIP_RETURN_CODE 77
          ENVIRONMENT "OMP_NUM_THREADS=1;OPENBLAS_NUM_THREADS=1")
      endif()
    endif()
  endforeach()
endif()
