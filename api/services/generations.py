"""How the API numbers generations, in one place for every view that reports one."""


def latest_generation(batches_recorded: int) -> int:
    """The index of the latest recorded generation: 0 = the initial population, -1 = none yet.

    The store counts recorded batches (the driver saves batch index + 1); clients compare this
    with ``generations_total``, so a finished study of n generations reads "n of n".
    """
    return batches_recorded - 1
