"""A clock the test moves by hand; `sleep` advances it instead of waiting."""


class FakeClock:
    def __init__(self, start: float = 1000.0):
        self.t = float(start)
        self.slept = 0.0

    def __call__(self) -> float:
        return self.t

    def advance(self, dt: float) -> float:
        self.t += dt
        return self.t

    def sleep(self, dt: float) -> None:
        if dt > 0:
            self.t += dt
            self.slept += dt
