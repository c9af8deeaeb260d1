# Sourced by the distributed scripts (bench-cluster.sh, distributed-fault-run.sh,
# distributed-k-learning.sh): sets the array `launch` to mpirun on this host (loopback, TCP), or,
# inside scripts/cluster-sim.sh, to its mpirun over the namespace hosts (one rank per host), and
# `where` to say which; lets Open MPI run as root.
export OMPI_ALLOW_RUN_AS_ROOT=1 OMPI_ALLOW_RUN_AS_ROOT_CONFIRM=1
if [ -n "${CLUSTER_SIM_MPIRUN:-}" ]; then
  launch=("$CLUSTER_SIM_MPIRUN" --map-by node --bind-to none)
  where="3 namespace hosts"
else
  launch=(mpirun --oversubscribe --mca btl tcp,self)
  where="one host (loopback)"
fi
