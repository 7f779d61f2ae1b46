"""Hand-built task DAGs shared by the scheduler tests (values from papers or derived by hand)."""

import networkx as nx

from warpvx.sched import cpu_gpu_dag

# Topcuoglu, Hariri, Wu, IEEE TPDS 13(3), 2002, Fig. 2: computation costs of tasks n1..n10 on
# processors P1, P2, P3 (table in Fig. 2) and communication costs on the edges.
TOPCUOGLU_COST = {
    1: (14, 16, 9), 2: (13, 19, 18), 3: (11, 13, 19), 4: (13, 8, 17), 5: (12, 13, 10),
    6: (13, 16, 9), 7: (7, 15, 11), 8: (5, 11, 14), 9: (18, 12, 20), 10: (21, 7, 16),
}
TOPCUOGLU_COMM = {
    (1, 2): 18, (1, 3): 12, (1, 4): 9, (1, 5): 11, (1, 6): 14, (2, 8): 19, (2, 9): 16,
    (3, 7): 23, (4, 8): 27, (4, 9): 23, (5, 9): 13, (6, 8): 15, (7, 10): 17, (8, 10): 11,
    (9, 10): 13,
}
# The paper's upward ranks (Table in §4.1 / Fig. 2 discussion, 3 decimals).
TOPCUOGLU_RANK = {
    1: 108.000, 2: 77.000, 3: 80.000, 4: 80.000, 5: 69.000, 6: 63.333, 7: 42.667, 8: 35.667,
    9: 44.333, 10: 14.667,
}
TOPCUOGLU_ORDER = [1, 3, 4, 2, 5, 6, 9, 7, 8, 10]


def topcuoglu_dag() -> nx.DiGraph:
    procs = ["P1", "P2", "P3"]
    dag = nx.DiGraph(processors=procs)
    for t, costs in TOPCUOGLU_COST.items():
        dag.add_node(t, cost=dict(zip(procs, costs)))
    for (u, v), c in TOPCUOGLU_COMM.items():
        dag.add_edge(u, v, comm=c)
    return dag


def fig51_dag() -> nx.DiGraph:
    """A DAG shaped like thesis Fig. 5.1, on 1 CPU + 1 GPU, no transfer costs.

    Tasks 0, 4, 7 are CPU-only, 1 is GPU-only, 2, 3, 5, 6 have both implementations
    (as in the thesis). Edges 0->1, 0->2, 0->3, 2->5, 5->6, 3->4, 6->7: tasks 1, 4, 7 are
    mutually independent, 4 depends on 3 and 7 on 6, as the thesis' Fig. 5.3 says. The costs
    (cpu, gpu) are chosen so that HEFT's rank list is the thesis' 0, 2, 5, 1, 3, 6, 4, 7:
    mean costs 0:2 1:10 2:3 3:2.5 4:7 5:4 6:3 7:5, upward ranks
    r7=5, r4=7, r6=3+5=8, r5=4+8=12, r3=2.5+7=9.5, r2=3+12=15, r1=10, r0=2+15=17.
    """
    tasks = {
        0: (2, None), 1: (None, 10), 2: (4, 2), 3: (3, 2), 4: (7, None), 5: (6, 2), 6: (4, 2),
        7: (5, None),
    }
    edges = [(0, 1), (0, 2), (0, 3), (2, 5), (5, 6), (3, 4), (6, 7)]
    return cpu_gpu_dag(tasks, edges, n_cpus=1)


def spans(schedule) -> dict:
    """task -> (processor, start, finish)."""
    return {t: (s.processor, s.start, s.finish) for t, s in schedule.tasks.items()}
