# The testbed's one image: every service of compose.yaml runs from it (`formation compose`).
# Build: docker build -t formation-testbed .   (docker compose up --build does it for you)
FROM python:3.12-slim

ENV PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    MPLBACKEND=Agg \
    MPLCONFIGDIR=/tmp/matplotlib

WORKDIR /app
# Only what the package needs: credentials, runs and the checkout's history stay out (.dockerignore).
COPY pyproject.toml README.md ./
COPY formation ./formation
COPY agent ./agent
COPY leader ./leader
COPY netem ./netem
COPY recorder ./recorder
COPY testbed ./testbed
RUN pip install . && rm -rf formation agent leader netem recorder testbed build
COPY scenarios ./scenarios

# Each service sets its own command; a bare `docker run` prints the CLI's help.
CMD ["formation", "--help"]
