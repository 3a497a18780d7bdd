"""roadlink's benchmark suite: `python -m benchmarks [--quick] [--only SECTION ...] [--json PATH]`.

Each section (a module in `benchmarks.sections`) measures one thing and returns a `Section` of
tables; the runner prints them as Markdown and writes them, with the machine, as JSON.
"""
