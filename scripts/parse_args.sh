# Sourced by scripts/env.sh and scripts/torch_only.sh.
# shellcheck shell=bash
# The scripts' one option parser: long3r_parse_args SPEC... -- "$@". A SPEC is
#   --name=var   the option takes a value, stored in $var;
#   --name?var   a flag: var=1;
#   @var         the one positional argument, stored in $var;
#   --=var       everything after a lone -- goes to the array var.
# -h / --help prints the script's header comment; anything else not in the
# table, or an option without its value, exits 2 naming the script.
long3r_parse_args() {
  local -A value=() flag=()
  local positional="" rest="" me
  me=$(basename "$0")
  while [ $# -gt 0 ] && [ "$1" != -- ]; do
    case "$1" in
      --=*) rest=${1#--=} ;;
      --*=*) value[${1%%=*}]=${1#*=} ;;
      --*\?*) flag[${1%%\?*}]=${1#*\?} ;;
      @*) positional=${1#@} ;;
      *) echo "long3r_parse_args: bad spec '$1' in $me" >&2; exit 2 ;;
    esac
    shift
  done
  [ $# -gt 0 ] && shift  # the -- between the table and the arguments
  local positional_set=0
  while [ $# -gt 0 ]; do
    if [ -n "$1" ] && [ -n "${value[$1]+set}" ]; then
      if [ $# -lt 2 ]; then
        echo "$me: $1 needs a value (see --help)" >&2
        exit 2
      fi
      printf -v "${value[$1]}" '%s' "$2"
      shift 2
    elif [ -n "$1" ] && [ -n "${flag[$1]+set}" ]; then
      printf -v "${flag[$1]}" '%s' 1
      shift
    elif [ "$1" = -h ] || [ "$1" = --help ]; then
      # The header: the comment lines after the shebang, without their '# '.
      awk 'NR > 1 && /^#/ { sub(/^# ?/, ""); print; next } NR > 1 { exit }' "$0"
      exit 0
    elif [ "$1" = -- ] && [ -n "$rest" ]; then
      shift
      eval "$rest=(\"\$@\")"
      return 0
    elif [ -n "$positional" ] && [ "$positional_set" = 0 ] && [ "${1#-}" = "$1" ]; then
      printf -v "$positional" '%s' "$1"
      positional_set=1
      shift
    else
      echo "$me: unknown argument $1 (see --help)" >&2
      exit 2
    fi
  done
}
