# scripts/build.sh's options reach CMake and its targets make (two configures
# of workspaces of their own; nothing is compiled).
if(LONG3R_WITH_ROS)
  add_test(NAME scripts_build_args
    COMMAND bash ${PROJECT_SOURCE_DIR}/test/scripts/test_build_args.sh
            ${PROJECT_BINARY_DIR}/test_tmp/build_args)
  set_tests_properties(scripts_build_args PROPERTIES TIMEOUT 600)
endif()
