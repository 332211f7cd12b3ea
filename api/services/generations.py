"""How the API numbers generations, in one place for every view that reports one."""


def latest_generation(batches_recorded: int, generations: int | None = None) -> int:
    """The index of the latest recorded generation: 0 = the initial population, -1 = none yet.

    The store counts recorded batches (the driver saves batch index + 1); clients compare this
    with ``generations_total``, so a finished study of n generations reads "n of n". The batches
    after the GA's last generation (extra replicates, validation) are not generations: with
    ``generations`` given the index stops there.
    """
    latest = batches_recorded - 1
    return latest if generations is None else min(latest, generations)
