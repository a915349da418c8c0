#!/bin/sh
# Container entrypoint: size PoCL's CPU device to the container's CPU quota, then `exec relight "$@"`.
#
# A container limited to N CPUs (docker --cpus N, a Kubernetes CPU limit) still sees every core of
# the host: PoCL would start one worker thread per host core and the quota would throttle them.
# POCL_CPU_MAX_CU_COUNT (compute units) and POCL_MAX_PTHREAD_COUNT (worker threads) are set to
# ceil(quota / period) from cgroup v2 `cpu.max` or cgroup v1 `cpu.cfs_quota_us`, capped by the
# CPUs this process may run on (nproc). Values already set in the environment win.
# RELIGHT_CGROUP_ROOT (default /sys/fs/cgroup) and RELIGHT_COMMAND (default relight) exist for the
# tests.
set -eu

root="${RELIGHT_CGROUP_ROOT:-/sys/fs/cgroup}"
quota=""
period=""
if [ -r "$root/cpu.max" ]; then
    read -r quota period < "$root/cpu.max" || true
elif [ -r "$root/cpu/cpu.cfs_quota_us" ] && [ -r "$root/cpu/cpu.cfs_period_us" ]; then
    quota=$(cat "$root/cpu/cpu.cfs_quota_us")
    period=$(cat "$root/cpu/cpu.cfs_period_us")
fi

cpus=$(nproc)
case "$quota" in
    ''|max|-*) ;;  # no quota
    *[!0-9]*) echo "relight-entrypoint: ignoring unreadable CPU quota '$quota'" >&2 ;;
    *)
        case "$period" in
            ''|*[!0-9]*|0) echo "relight-entrypoint: ignoring CPU quota with period '$period'" >&2 ;;
            *)
                limit=$(( (quota + period - 1) / period ))
                if [ "$limit" -lt "$cpus" ]; then cpus=$limit; fi
                ;;
        esac
        ;;
esac
if [ "$cpus" -lt 1 ]; then cpus=1; fi

export POCL_CPU_MAX_CU_COUNT="${POCL_CPU_MAX_CU_COUNT:-$cpus}"
export POCL_MAX_PTHREAD_COUNT="${POCL_MAX_PTHREAD_COUNT:-$cpus}"
exec "${RELIGHT_COMMAND:-relight}" "$@"
