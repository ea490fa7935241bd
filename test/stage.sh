#!/usr/bin/env bash
# One stage of `make test`: runs the command, prints how long it took and appends the stage's
# line to the summary file `make test` prints at its end (passed or FAILED, minutes:seconds).
#   test/stage.sh SUMMARY_FILE NAME COMMAND...
summary=$1 name=$2
shift 2
start=$(date +%s)
"$@"
rc=$?
s=$(( $(date +%s) - start ))
line=$(printf '  %-28s %-7s %2d min %02d s' "$name" "$([ $rc = 0 ] && echo passed || echo FAILED)" $((s / 60)) $((s % 60)))
echo "$line" >> "$summary"
echo "stage $name: $([ $rc = 0 ] && echo passed || echo "FAILED (exit $rc)") in $((s / 60)) min $((s % 60)) s"
if [ $rc != 0 ]; then
  echo "make test stages:"; cat "$summary"
fi
exit $rc
