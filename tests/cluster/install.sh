#!/usr/bin/env bash
# Prerequisites of `make test-cluster`, from Debian's packages (needs root):
# PostgreSQL for the tracking server, SLURM + munge for the one-node cluster, Chromium for
# the UI screenshots. Exits non-zero with a message when something cannot be installed.
set -euo pipefail
need=()
command -v initdb >/dev/null 2>&1 || ls /usr/lib/postgresql/*/bin/initdb >/dev/null 2>&1 || need+=(postgresql)
command -v slurmctld >/dev/null 2>&1 || need+=(slurm-wlm)
command -v munged >/dev/null 2>&1 || [ -x /usr/sbin/munged ] || need+=(munge)
command -v chromium >/dev/null 2>&1 || need+=(chromium)
if [ ${#need[@]} -eq 0 ]; then
    echo "cluster prerequisites present"; exit 0
fi
if [ "$(id -u)" != 0 ]; then
    echo "error: test-cluster needs ${need[*]} from Debian; run as root (apt-get install -y ${need[*]})" >&2
    exit 2
fi
echo "installing ${need[*]} from Debian"
export DEBIAN_FRONTEND=noninteractive
apt-get update -qq
apt-get install -y -qq --no-install-recommends "${need[@]}" >/dev/null
echo "cluster prerequisites installed"
