"""The benchmarks ``runners.bench`` and ``runners.bench_dataset`` run: the planner's speed against its
loop reference (``planner_speed``), the batched IK's (``ik_speed``) and the dataset engine's
(``dataset_speed``)."""
