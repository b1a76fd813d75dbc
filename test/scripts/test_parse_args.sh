#!/usr/bin/env bash
# The scripts' option parser (scripts/parse_args.sh, long3r_parse_args): values,
# flags, the positional argument, the rest after --, --help, and the errors.
set -uo pipefail
source "$(dirname "$0")/../../scripts/parse_args.sh"
failures=0
check() {  # name, expected, actual
  if [ "$2" != "$3" ]; then
    echo "FAIL $1: expected '$2', got '$3'"
    failures=$((failures + 1))
  fi
}
parse() {  # runs the parser on "$@" in a subshell; prints the variables it set
  (
    model=default out="" keep=0 extra=()
    long3r_parse_args --model=model --keep?keep @out --=extra -- "$@"
    echo "model=$model keep=$keep out=$out extra=${extra[*]:-} n=${#extra[@]}"
  )
}
check values "model=a b keep=1 out=dir extra= n=0" "$(parse --model "a b" --keep dir)"
check defaults "model=default keep=0 out= extra= n=0" "$(parse)"
check rest "model=m keep=0 out= extra=--x 1 -- y n=4" "$(parse --model m -- --x 1 -- y)"
check "last wins" "model=2 keep=0 out= extra= n=0" "$(parse --model 1 --model 2)"
out=$(parse --modle x 2>&1); rc=$?
check "unknown rc" 2 "$rc"
check "unknown message" "test_parse_args.sh: unknown argument --modle (see --help)" "$out"
out=$(parse --model 2>&1); rc=$?
check "missing value rc" 2 "$rc"
check "missing value message" "test_parse_args.sh: --model needs a value (see --help)" "$out"
check "empty positional" "model=default keep=0 out= extra= n=0" "$(parse "")"
out=$(parse one two 2>&1); rc=$?
check "second positional rc" 2 "$rc"
out=$(parse --help); rc=$?
check "help rc" 0 "$rc"
check "help text" "The scripts' option parser (scripts/parse_args.sh, long3r_parse_args): values," \
  "$(echo "$out" | head -1)"
out=$( (long3r_parse_args --x=y -- --z 1) 2>&1); rc=$?
check "no positional rc" 2 "$rc"
out=$( (long3r_parse_args bad -- ) 2>&1); rc=$?
check "bad spec rc" 2 "$rc"
[ "$failures" = 0 ] && echo "all checks passed"
exit "$failures"
