# End-to-end test of long3r_train (python driver): every curriculum stage of
# the tiny model on generated scenes, interruption and --resume, the outputs,
# and the trained model loaded by long3r_ckpt_info and long3r_reconstruct.
if(TARGET app_long3r_train AND TARGET app_long3r_synth AND TARGET app_long3r_reconstruct
   AND TARGET app_long3r_ckpt_info)
  add_test(NAME train_cli
    COMMAND /usr/bin/python3 ${PROJECT_SOURCE_DIR}/test/train/train_cli_test.py
      --train $<TARGET_FILE:app_long3r_train>
      --synth $<TARGET_FILE:app_long3r_synth>
      --reconstruct $<TARGET_FILE:app_long3r_reconstruct>
      --ckpt-info $<TARGET_FILE:app_long3r_ckpt_info>
      --workdir ${PROJECT_BINARY_DIR}/test_tmp/train_cli)
  set_tests_properties(train_cli PROPERTIES
    ENVIRONMENT "OMP_NUM_THREADS=2;OPENBLAS_NUM_THREADS=1" TIMEOUT 300)
endif()
