# One image for every demcal process: `demcal serve` (API, dashboard, study driver),
# `demcal worker` (DEM trials from the Redis queue) and `demcal db upgrade` (migrations).
# Used by docker-compose.yml; build with `docker build -t demcal .`. The `liggghts` target adds
# Debian's LIGGGHTS for workers that run the LIGGGHTS engine (dem/engines/liggghts.py):
# `docker build --target liggghts -t demcal-liggghts .`.
FROM python:3.11-slim AS demcal

ENV PYTHONDONTWRITEBYTECODE=1 \
    PYTHONUNBUFFERED=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    DEMCAL_DATA_DIR=/data \
    # numba writes compiled kernels here (cache=True), so a restarted worker skips compilation.
    NUMBA_CACHE_DIR=/home/demcal/.cache/numba

WORKDIR /src
# Dependencies first: this layer is rebuilt only when pyproject.toml changes, not on every edit.
COPY pyproject.toml README.md ./
RUN mkdir -p api worker dem optimizer migrations \
    && pip install . \
    && pip uninstall -y demcal
COPY api ./api
COPY worker ./worker
COPY dem ./dem
COPY optimizer ./optimizer
COPY migrations ./migrations
COPY examples /opt/demcal/examples
RUN pip install --no-deps . && rm -rf /src

# Never run as root: the API is exposed and workers run user-supplied meshes.
RUN useradd --create-home --uid 10001 demcal \
    && mkdir -p /data "$NUMBA_CACHE_DIR" \
    && chown -R demcal:demcal /data /home/demcal
USER demcal
WORKDIR /home/demcal

EXPOSE 8000
CMD ["demcal", "serve"]

# Workers with LIGGGHTS: the same image plus Debian's package (MPI singleton runs, one core each).
FROM demcal AS liggghts
USER root
RUN apt-get update \
    && apt-get install -y --no-install-recommends liggghts \
    && rm -rf /var/lib/apt/lists/* \
    && liggghts -h > /dev/null
USER demcal

# The default target: the plain image.
FROM demcal
