#!/usr/bin/env bash
# A cluster on one machine for Open MPI: N network namespaces as hosts h0..h(N-1), each with its
# own address on a private subnet, joined by a bridge (in a namespace of its own, so the machine's
# own network stack carries none of the traffic), each host's link shaped with tc htb to a rate in
# both directions; a hostfile and an rsh agent for mpirun that runs a command inside the host's
# namespace (with its own host name), so `mpirun --hostfile` starts one orted per "host".
# docs/distributed.md, "Several hosts on one machine".
#
# Usage (as root):
#   bash scripts/cluster-sim.sh run [--hosts N] [--rate RATE] -- COMMAND [ARGS...]
#       makes the cluster, runs COMMAND (in the machine's namespace) with the variables below,
#       and removes everything again on every exit path (also on errors and signals). Its exit
#       status is COMMAND's.
#   bash scripts/cluster-sim.sh check      exits 0 when namespaces can be made here, else 77
#       (the conventional "skipped") with the reason on stderr.
# Options: --hosts N (default 3), --rate RATE (tc's syntax: 1gbit, 10gbit, 100mbit; default
# 1gbit), --subnet A.B.C (default 10.233.7: hosts at A.B.C.1 ..).
#
# COMMAND sees:
#   CLUSTER_SIM_DIR        a folder with the files below (removed at the end)
#   CLUSTER_SIM_HOSTFILE   the hostfile: h0 .. h(N-1), one slot each
#   CLUSTER_SIM_AGENT      the rsh agent: `agent HOST CMD...` runs CMD in HOST's namespace
#   CLUSTER_SIM_MPIRUN     `$CLUSTER_SIM_MPIRUN ARGS...` runs mpirun on h0 with the hostfile, the
#                          agent and the MCA settings of this cluster (tcp BTL on the subnet only)
#   CLUSTER_SIM_CUT / CLUSTER_SIM_RESTORE   `$CLUSTER_SIM_CUT HOST`: the host's cable out of the
#                          bridge (its switch-side veth down) / back in
#   CLUSTER_SIM_SUBNET     the subnet, CIDR
#   CLUSTER_SIM_NS_PREFIX  the namespaces' prefix (namespace PREFIX-hI is host hI)
set -euo pipefail

SKIP=77
hosts=3
rate=1gbit
subnet=10.233.7

die() { echo "cluster-sim: error: $*" >&2; exit 2; }

# Whether this process may make network namespaces (root with CAP_SYS_ADMIN and CAP_NET_ADMIN,
# ip and tc present, the htb qdisc loadable). Prints the reason and returns 1 when not.
can_make() {
  local why=""
  if [ "$(id -u)" != 0 ]; then
    why="needs root (CAP_SYS_ADMIN, CAP_NET_ADMIN) to make network namespaces; running as uid $(id -u)"
  elif ! command -v ip >/dev/null || ! command -v tc >/dev/null || ! command -v unshare >/dev/null; then
    why="needs ip, tc (iproute2) and unshare (util-linux)"
  else
    local probe="dxsprobe$$"
    if ! ip netns add "$probe" 2>/dev/null; then
      why="cannot make a network namespace here (ip netns add failed: no privileges or no namespace support)"
    else
      if ! ip netns exec "$probe" ip link add "p$$" type veth peer name "q$$" 2>/dev/null; then
        why="cannot make a veth pair in a network namespace"
      elif ! ip netns exec "$probe" tc qdisc add dev "p$$" root handle 1: htb 2>/dev/null; then
        why="the htb qdisc is not available (tc qdisc add ... htb failed)"
      fi
      ip netns del "$probe" 2>/dev/null || true
    fi
  fi
  if [ -n "$why" ]; then
    echo "cluster-sim: cannot simulate hosts: $why" >&2
    return 1
  fi
}

mode=${1:-}
[ -n "$mode" ] || { sed -n '2,/^set -e/p' "$0" | sed 's/^# \{0,1\}//;$d' >&2; exit 2; }
shift
if [ "$mode" = check ]; then
  can_make || exit $SKIP
  exit 0
fi
[ "$mode" = run ] || die "unknown mode '$mode' (run, check)"
while [ $# -gt 0 ]; do
  case $1 in
    --hosts) hosts=$2; shift 2 ;;
    --rate) rate=$2; shift 2 ;;
    --subnet) subnet=$2; shift 2 ;;
    --) shift; break ;;
    *) die "unknown option '$1'" ;;
  esac
done
[ $# -gt 0 ] || die "no command after --"
[[ $hosts =~ ^[0-9]+$ ]] && [ "$hosts" -ge 1 ] && [ "$hosts" -le 200 ] || die "--hosts must be 1..200"
[[ $subnet =~ ^[0-9]+\.[0-9]+\.[0-9]+$ ]] || die "--subnet must be A.B.C"
[[ $rate =~ ^[0-9]+(\.[0-9]+)?[kmg]?bit$ ]] || die "--rate must be like 1gbit, 10gbit, 100mbit"
can_make || exit $SKIP

p="dxs$$"                     # unique per cluster: concurrent clusters do not collide
sw="$p-sw"
dir=$(mktemp -d "${TMPDIR:-/tmp}/cluster-sim.XXXXXX")
made=()
child=""

cleanup() {
  local rc=$?
  trap - EXIT INT TERM HUP
  [ -n "${child:-}" ] && kill -TERM "$child" 2>/dev/null
  # Processes still inside the hosts' namespaces are this cluster's (mpirun, orteds, ranks).
  for ns in "${made[@]}"; do
    for pid in $(ip netns pids "$ns" 2>/dev/null); do kill -KILL "$pid" 2>/dev/null || true; done
  done
  for ns in "${made[@]}"; do
    ip netns del "$ns" 2>/dev/null || true
    rm -rf "/etc/netns/$ns"
  done
  rm -rf "$dir"
  exit "$rc"
}
trap cleanup EXIT
trap 'exit 130' INT
trap 'exit 143' TERM
trap 'exit 129' HUP

# htb on a device's egress: one class at `rate`, a burst of a few ms at that rate (a too small
# burst caps a fast link below its rate with the timer's granularity).
shape() {
  local ns=$1 dev=$2
  ip netns exec "$ns" tc qdisc add dev "$dev" root handle 1: htb default 10
  ip netns exec "$ns" tc class add dev "$dev" parent 1: classid 1:10 htb rate "$rate" ceil "$rate" quantum 60000 \
    burst 1m cburst 1m
}

ip netns add "$sw"; made+=("$sw")
ip netns exec "$sw" ip link set lo up
ip netns exec "$sw" ip link add br0 type bridge
ip netns exec "$sw" ip link set br0 up
: > "$dir/hostfile"
hostlines=""
for i in $(seq 0 $((hosts - 1))); do
  hostlines+="$subnet.$((i + 1)) h$i"$'\n'
done
for i in $(seq 0 $((hosts - 1))); do
  ns="$p-h$i"
  ip netns add "$ns"; made+=("$ns")
  ip link add "${p}h$i" type veth peer name "${p}s$i"
  ip link set "${p}h$i" netns "$ns"
  ip link set "${p}s$i" netns "$sw"
  ip netns exec "$ns" ip link set lo up
  ip netns exec "$ns" ip link set "${p}h$i" name eth0
  ip netns exec "$ns" ip addr add "$subnet.$((i + 1))/24" dev eth0
  ip netns exec "$ns" ip link set eth0 up
  ip netns exec "$sw" ip link set "${p}s$i" name "v$i"
  ip netns exec "$sw" ip link set "v$i" master br0
  ip netns exec "$sw" ip link set "v$i" up
  shape "$ns" eth0       # host -> switch
  shape "$sw" "v$i"      # switch -> host
  # `ip netns exec` binds /etc/netns/NS/hosts over /etc/hosts: the hosts resolve each other.
  mkdir -p "/etc/netns/$ns"
  printf '127.0.0.1 localhost\n%s' "$hostlines" > "/etc/netns/$ns/hosts"
  echo "h$i slots=1" >> "$dir/hostfile"
done

# The rsh agent: `agent HOST CMD...` runs CMD (one shell string, as ssh joins its arguments) in
# HOST's namespace with HOST as its host name (a UTS namespace of its own), so Open MPI's daemon
# there reports a host of its own. The namespaces share the file system: the same binary paths.
cat > "$dir/agent" <<AGENT
#!/usr/bin/env bash
# rsh agent of cluster-sim $p (plm_rsh_agent): runs a command inside the host's namespace.
set -euo pipefail
host=\$1; shift
case \$host in h[0-9]*) ;; *) echo "cluster-sim agent: unknown host '\$host'" >&2; exit 255 ;; esac
[ -e "/run/netns/$p-\$host" ] || { echo "cluster-sim agent: no host '\$host'" >&2; exit 255; }
exec ip netns exec "$p-\$host" unshare --uts /bin/sh -c "hostname \$host && \$*"
AGENT
cat > "$dir/mpirun" <<MPIRUN
#!/usr/bin/env bash
# mpirun on h0 of cluster-sim $p with its hostfile and agent, TCP on the cluster's subnet only.
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
exec "$dir/agent" h0 "\$(printf '%q ' mpirun --hostfile "$dir/hostfile" \
  --mca plm_rsh_agent "$dir/agent" --mca btl tcp,self \
  --mca btl_tcp_if_include $subnet.0/24 --mca oob_tcp_if_include $subnet.0/24 "\$@")"
MPIRUN
for what in cut restore; do
  state=down; [ $what = restore ] && state=up
  cat > "$dir/$what" <<LINK
#!/usr/bin/env bash
# cluster-sim $p: the host's switch-side veth $state.
set -euo pipefail
i=\${1#h}
exec ip netns exec "$sw" ip link set "v\$i" $state
LINK
done
chmod +x "$dir/agent" "$dir/mpirun" "$dir/cut" "$dir/restore"

export CLUSTER_SIM_DIR="$dir" CLUSTER_SIM_HOSTFILE="$dir/hostfile" CLUSTER_SIM_AGENT="$dir/agent" \
  CLUSTER_SIM_MPIRUN="$dir/mpirun" CLUSTER_SIM_CUT="$dir/cut" CLUSTER_SIM_RESTORE="$dir/restore" \
  CLUSTER_SIM_SUBNET="$subnet.0/24" CLUSTER_SIM_NS_PREFIX="$p"
echo "cluster-sim: $hosts hosts h0..h$((hosts - 1)) at $subnet.1-$hosts, links at $rate ($p)" >&2
# In the background, so a signal to this script runs the trap at once (bash runs traps only
# between foreground commands).
"$@" &
child=$!
set +e
wait "$child"
rc=$?
set -e
child=""
exit $rc
