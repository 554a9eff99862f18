# The testbed's one image: every service of compose.yaml runs from it (`formation compose`).
# Build: docker build -t formation-testbed .   (docker compose up --build does it for you)
# Under podman without a registry, deploy/podman.sh makes this FROM image locally (README).
FROM python:3.12-slim

ENV PYTHONUNBUFFERED=1 \
    PYTHONDONTWRITEBYTECODE=1 \
    PIP_NO_CACHE_DIR=1 \
    PIP_DISABLE_PIP_VERSION_CHECK=1 \
    MPLBACKEND=Agg \
    MPLCONFIGDIR=/tmp/matplotlib

WORKDIR /app
# The dependencies first, in a layer of their own: a change to the code does not reinstall them.
# (The packages' folders and the README are empty here, so an edit to them does not reinstall
# the dependencies; the project itself is uninstalled again.)
# EXTRAS="[ros2]": the ROS 2 bodies' packages (formation compose sets it for such a scenario).
ARG EXTRAS=""
COPY pyproject.toml ./
RUN mkdir formation shell body analysis agent leader netem recorder testbed && touch README.md \
    && pip install ".${EXTRAS}" && pip uninstall -y formation-testbed \
    && rm -rf formation shell body analysis agent leader netem recorder testbed build *.egg-info README.md
# Only what the package needs: credentials, runs and the checkout's history stay out (.dockerignore).
COPY formation ./formation
COPY shell ./shell
COPY body ./body
COPY analysis ./analysis
COPY agent ./agent
COPY leader ./leader
COPY netem ./netem
COPY recorder ./recorder
COPY testbed ./testbed
COPY README.md ./
RUN pip install --no-deps . && rm -rf formation shell body analysis agent leader netem recorder testbed build *.egg-info
# Plug-in packages (docs/plugins.md): pip requirements, or folders of the build context, e.g.
#   docker build --build-arg PLUGINS=./examples/formation-plugins-example -t formation-testbed .
# compose.plugins.yaml passes it. The testbed itself is installed, so pip keeps it.
ARG PLUGINS=""
COPY examples ./examples
RUN if [ -n "$PLUGINS" ]; then pip install $PLUGINS && pip check; fi; rm -rf examples
# The shipped scenarios are in the package too (formation simulate paper); this copy keeps
# `formation simulate scenarios/paper.toml` working in /app.
COPY formation/scenarios ./scenarios

# Each service sets its own command (and compose its user); a bare `docker run` prints the CLI's help.
CMD ["formation", "--help"]
