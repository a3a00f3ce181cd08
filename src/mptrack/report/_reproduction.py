def write_reproduction_report(*a, **k): raise NotImplementedError
