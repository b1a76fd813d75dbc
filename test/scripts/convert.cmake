# Round trip of scripts/convert_checkpoint.py on the golden weights (official
# DUSt3R / Spann3R style .pth -> safetensors -> C++ loader, and back). Needs
# /usr/bin/python3 with PyTorch (Debian's python3-torch); skipped without it.
if(EXISTS /usr/bin/python3)
  set(LONG3R_TORCH_PYTHON /usr/bin/python3 CACHE FILEPATH "Python with PyTorch for script tests")
else()
  find_package(Python3 COMPONENTS Interpreter)
  set(LONG3R_TORCH_PYTHON "${Python3_EXECUTABLE}" CACHE FILEPATH "Python with PyTorch for script tests")
endif()
if(LONG3R_TORCH_PYTHON AND TARGET app_long3r_ckpt_info)
  add_test(NAME convert_checkpoint_roundtrip
    COMMAND ${LONG3R_TORCH_PYTHON} ${PROJECT_SOURCE_DIR}/test/scripts/test_convert_roundtrip.py
            --script ${PROJECT_SOURCE_DIR}/scripts/convert_checkpoint.py
            --info $<TARGET_FILE:app_long3r_ckpt_info>
            --golden ${LONG3R_GOLDEN_DIR}
            --linear-golden ${LONG3R_GOLDEN_DIR}/dust3r_linear_sq64)
  set_tests_properties(convert_checkpoint_roundtrip PROPERTIES
    SKIP_RETURN_CODE 77 TIMEOUT 300 ENVIRONMENT "OMP_NUM_THREADS=1")
endif()
