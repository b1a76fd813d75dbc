# The shipped model beats the constant-depth baseline on held-out generated
# sequences (python driver around long3r_model_eval; thresholds in the script).
if(TARGET app_long3r_model_eval)
  add_test(NAME shipped_model
    COMMAND /usr/bin/python3 ${PROJECT_SOURCE_DIR}/test/train/shipped_model_test.py
      --eval $<TARGET_FILE:app_long3r_model_eval>
      --model ${PROJECT_SOURCE_DIR}/models/default.safetensors)
  set_tests_properties(shipped_model PROPERTIES
    ENVIRONMENT "OMP_NUM_THREADS=2;OPENBLAS_NUM_THREADS=1" TIMEOUT 300)

  # scripts/loss_probe.sh (the model card's diagnosis) on the shipped model.
  add_test(NAME loss_probe
    COMMAND /usr/bin/python3 ${PROJECT_SOURCE_DIR}/test/train/loss_probe_test.py
      --script ${PROJECT_SOURCE_DIR}/scripts/loss_probe.sh
      --bin $<TARGET_FILE_DIR:app_long3r_model_eval>
      --model ${PROJECT_SOURCE_DIR}/models/default.safetensors)
  set_tests_properties(loss_probe PROPERTIES
    ENVIRONMENT "OMP_NUM_THREADS=2;OPENBLAS_NUM_THREADS=1" TIMEOUT 300)
endif()
