# End-to-end test of long3r_reconstruct with a random tiny model (python driver).
if(TARGET app_long3r_reconstruct AND TARGET app_long3r_make_random_model AND TARGET app_long3r_synth)
  add_test(NAME reconstruct_cli
    COMMAND /usr/bin/python3 ${PROJECT_SOURCE_DIR}/test/pipeline/reconstruct_cli_test.py
      --synth $<TARGET_FILE:app_long3r_synth>
      --make-model $<TARGET_FILE:app_long3r_make_random_model>
      --reconstruct $<TARGET_FILE:app_long3r_reconstruct>
      --workdir ${PROJECT_BINARY_DIR}/test_tmp/reconstruct_cli)
  set_tests_properties(reconstruct_cli PROPERTIES
    ENVIRONMENT "OMP_NUM_THREADS=2;OPENBLAS_NUM_THREADS=1" TIMEOUT 300)
endif()
