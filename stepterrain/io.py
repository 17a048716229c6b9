"""placeholder, replaced below"""
def load_dem(path):
    raise NotImplementedError
def sample_dem():
    raise NotImplementedError
