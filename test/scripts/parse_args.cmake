# The scripts' one option parser (scripts/parse_args.sh).
add_test(NAME scripts_parse_args COMMAND bash ${PROJECT_SOURCE_DIR}/test/scripts/test_parse_args.sh)
