"""One module per benchmark suite, each exposing SUITE (or SUITES) built from benchmarks.harness.Suite."""
