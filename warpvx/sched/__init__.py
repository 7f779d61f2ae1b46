"""DAG scheduling: baseline, HEFT, XEFT and best-of policies, metrics, generator, executor."""

from .schedule import Schedule, ScheduledTask
