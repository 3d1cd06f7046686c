"""The report comparing methods across runs (``python -m experiments.report``), in four steps:

* :mod:`.discover`: find the runs (``metrics.json``) below the given directories, load their side files
  (``test_predictions.npz``, ``handling/per_input.npz``, ``model_size.json``, ``bench/results.json``), name
  and order their methods and sizes, group them by data set;
* :mod:`.aggregate`: the numbers, pooled over seeds (per-round curves, Table 3, Pareto points and fronts,
  failure breakdowns, costs);
* :mod:`.markdown` and :mod:`.tradeoff_tables`: the tables of ``report.md``; :mod:`.plots`: the charts;
* :mod:`.build`: all of it written into the output directory (``report.md``, ``table3.csv``, ``report.json``,
  ``*.png``).

One run's own reporting (``python -m experiments.run``): :mod:`.summary` (the printed summary and the line per round),
:mod:`.tensorboard` (the scalars and pictures beside the trainings' own) and :mod:`.run_report` (the pipeline's
reporter that calls them).
"""
