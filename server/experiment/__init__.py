"""The paper's Sec. 4 experiments: a declarative design, trials run through the simulator in
the browser (or headless, for simulated observers), results as BIDS behavioural data, and the
psychometric analysis of those results (docs/experiments.md)."""
