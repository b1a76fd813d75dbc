# End-to-end test of long3r_train (python driver): every curriculum stage of
# the tiny model on generated scenes, interruption and --resume, the outputs
# (the blind control's columns among them), and the trained model loaded by
# long3r_ckpt_info, long3r_reconstruct and long3r_model_eval --blind-control.
if(TARGET app_long3r_train AND TARGET app_long3r_synth AND TARGET app_long3r_reconstruct
   AND TARGET app_long3r_ckpt_info AND TARGET app_long3r_model_eval)
  add_test(NAME train_cli
    COMMAND /usr/bin/python3 ${PROJECT_SOURCE_DIR}/test/train/train_cli_test.py
      --train $<TARGET_FILE:app_long3r_train>
      --model-eval $<TARGET_FILE:app_long3r_model_eval>
      --synth $<TARGET_FILE:app_long3r_synth>
      --reconstruct $<TARGET_FILE:app_long3r_reconstruct>
      --ckpt-info $<TARGET_FILE:app_long3r_ckpt_info>
      --workdir ${PROJECT_BINARY_DIR}/test_tmp/train_cli)
  set_tests_properties(train_cli PROPERTIES
    ENVIRONMENT "OMP_NUM_THREADS=2;OPENBLAS_NUM_THREADS=1" TIMEOUT 300)
endif()

# scripts/train_gpu.sh, checked on the CPU: the trainer and the generator
# build with nothing but a libtorch and the header-only dependencies packed
# as for a GPU machine (OpenCV, PCL and the system Eigen kept out), train a
# few steps of the real GPU recipe with a data thread, and write the folder
# to bring back; without a GPU the real run says why and exits 3.
if(LONG3R_HAVE_CV)  # checked from the full build; the dry run makes the torch-only one
  add_test(NAME train_gpu_cpu_dry_run
    COMMAND /usr/bin/python3 ${PROJECT_SOURCE_DIR}/test/train/train_gpu_dry_run_test.py
      --root ${PROJECT_SOURCE_DIR} --workdir ${PROJECT_BINARY_DIR}/test_tmp/train_gpu)
  set_tests_properties(train_gpu_cpu_dry_run PROPERTIES
    ENVIRONMENT "OPENBLAS_NUM_THREADS=1" TIMEOUT 1500)
endif()

# scripts/bench_train.py on the tiny model: its table, checked (figures are
# not asserted; the benchmark prints them).
if(TARGET app_long3r_train)
  add_test(NAME bench_train
    COMMAND /usr/bin/python3 ${PROJECT_SOURCE_DIR}/test/train/bench_train_test.py
      ${PROJECT_SOURCE_DIR} $<TARGET_FILE:app_long3r_train>)
  set_tests_properties(bench_train PROPERTIES
    ENVIRONMENT "OMP_NUM_THREADS=1;OPENBLAS_NUM_THREADS=1" TIMEOUT 300)
endif()

# scripts/bench_pairs.py without the reference, on a frame cache of its own:
# its table checked (rates are printed, not asserted).
if(TARGET app_long3r_train AND TARGET app_long3r_frame_cache AND "gloo" IN_LIST LONG3R_DATA_PARALLEL)
  add_test(NAME bench_pairs
    COMMAND /usr/bin/python3 ${PROJECT_SOURCE_DIR}/test/train/bench_pairs_test.py
      ${PROJECT_SOURCE_DIR} $<TARGET_FILE_DIR:app_long3r_train>
      ${PROJECT_BINARY_DIR}/test_tmp/bench_pairs)
  set_tests_properties(bench_pairs PROPERTIES
    ENVIRONMENT "OMP_NUM_THREADS=1;OPENBLAS_NUM_THREADS=1" TIMEOUT 300)
endif()

# Data-parallel training under torchrun (--no_python) with Gloo on this CPU:
# bit-identical replicas, the same weights as one process on the same global
# batch, a two-rank checkpoint resumed in one process, a killed rank.
find_program(LONG3R_TORCHRUN torchrun)
if(TARGET app_long3r_train AND LONG3R_TORCHRUN AND "gloo" IN_LIST LONG3R_DATA_PARALLEL)
  add_test(NAME train_distributed
    COMMAND /usr/bin/python3 ${PROJECT_SOURCE_DIR}/test/train/train_distributed_test.py
      --train $<TARGET_FILE:app_long3r_train> --torchrun ${LONG3R_TORCHRUN}
      --workdir ${PROJECT_BINARY_DIR}/test_tmp/train_distributed)
  set_tests_properties(train_distributed PROPERTIES
    ENVIRONMENT "OMP_NUM_THREADS=1;OPENBLAS_NUM_THREADS=1" TIMEOUT 900)
elseif(TARGET app_long3r_train)
  message(STATUS "long3r: no torchrun or no Gloo backend: train_distributed not registered")
endif()
