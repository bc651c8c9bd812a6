"""`python -m examples.learn_motion --framework torch|jax --minutes 4`: render the data, train, report."""

from examples.learn_motion.run import main

if __name__ == "__main__":
    raise SystemExit(main())
