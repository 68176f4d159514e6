#!/bin/sh
# The image's entry point (Dockerfile). `docker run IMAGE [irrrd options]` runs the daemon with the
# image's configuration and its journal in the volume; `docker run IMAGE irrr-<tool> [options]`
# runs one of the client tools instead (irrr-inject, irrr-listen, irrr-view, irrr-batch, ...), so
# that they need no --entrypoint. exec: the program is PID 1 and receives docker's signals itself.
case "$1" in
  irrr-*) exec "$@" ;;
  irrrd) shift ;;
esac
exec /usr/local/bin/irrrd --config /etc/irrrd/irrrd.json --journal /var/lib/irrrd/journal "$@"
