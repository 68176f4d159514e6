#!/bin/sh
# Runs a command inside a private network namespace whose only interface is loopback, with a
# multicast route over it, so that LCM's UDP multicast never leaves the test. As root (CI) a plain
# network namespace; otherwise a user namespace too. Exits 77 (CTest: skipped) where the system
# allows neither.
set -eu
if [ "$(id -u)" -eq 0 ]; then namespace="unshare -n"; else namespace="unshare -rn"; fi
if ! $namespace true 2>/dev/null; then
  echo "SKIP: cannot create a private network namespace ($namespace)"
  exit 77
fi
exec $namespace sh -c 'ip link set lo up && ip route add 224.0.0.0/4 dev lo && exec "$0" "$@"' "$@"
