"""The MLflow UI as a person sees it: a real ``mlflow server`` and headless Chromium (Selenium).

The browser test serves a store holding one small sweep (2 faults x 2 optimisers, 4 generations
each) with ``mlflow server --workers 1`` on 127.0.0.1, opens the UI in Debian's ``chromium``
driven by Debian's ``chromium-driver``, and checks the pages a person uses to compare runs: the
experiment's runs table, the sweep's parent run with its four children, the compare view of the
children (the swept params, FAR and MDR) and the per-generation hypervolume chart. Screenshots go
to ``$MOSD_UI_SHOTS`` (default: the test's temporary directory); ``docs/img/mlflow-compare.png``
is one of them.

``mosd ui`` (mosd/app/ui.py) is checked the way a person uses it: a fresh browser opens the
experiment list it prints, clicks the experiment once and must land on the runs table with the
FAR and MDR columns (MLflow's own server lands that click on its GenAI overview).

Chromium, chromedriver and selenium are test dependencies (``.ci/run`` installs the first two
with apt, the ``test`` extra brings selenium): when one is missing the test fails, it does not skip.
The browser test is marked slow like the other real-server tests (about 45 s: the sweep, the
server's start, the browser).
"""
from __future__ import annotations

import os
import shutil
import subprocess
import sys
import tempfile
import time
import urllib.request
from pathlib import Path

import pytest

from mosd.app.mlflow_client import MlflowStore
from mosd.app.serving import free_port, stop_process_group
from mosd.app.settings import TrackingSettings

#: the tag MLflow reads for an experiment's kind, and the kind of a training-runs experiment
#: (MLflow's ExperimentKind.CUSTOM_MODEL_DEVELOPMENT; its UI labels it "Machine learning")
KIND_TAG, TRAINING_KIND = "mlflow.experimentKind", "custom_model_development"
CHROMIUM, CHROMEDRIVER = "/usr/bin/chromium", "/usr/bin/chromedriver"
#: root in a container: no sandbox; no connection to Google's services on a closed network
CHROMIUM_FLAGS = ("--headless", "--no-sandbox", "--disable-gpu", "--disable-quic", "--no-first-run",
                  "--disable-background-networking", "--disable-component-update", "--disable-sync",
                  "--window-size=1400,900")
SWEEP = ["-m", "+fault=offset,variance", "optimizer=mopso,nsga2", "optimizer.pop_size=6", "optimizer.n_gen=4",
         "budget.n_test=2", "budget.n_train=2", "budget.n_calibration=2", "optimizer.n_jobs=1", "progress=false",
         "scenario.duration=3"]


def _experiment_tags(uri: str) -> dict:
    from mlflow.tracking import MlflowClient

    return MlflowClient(tracking_uri=uri).get_experiment_by_name("mosd").tags


def test_mosd_makes_its_experiment_a_training_runs_experiment(tmp_path):
    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    store = MlflowStore(TrackingSettings(uri, (tmp_path / "art").as_uri(), "mosd"))
    assert store.experiment_id()
    assert _experiment_tags(uri).get(KIND_TAG) == TRAINING_KIND


def test_an_experiment_made_before_gets_the_kind_and_a_chosen_kind_is_kept(tmp_path):
    from mlflow.tracking import MlflowClient

    uri = f"sqlite:///{tmp_path / 'mlflow.db'}"
    settings = TrackingSettings(uri, (tmp_path / "art").as_uri(), "mosd")
    client = MlflowClient(tracking_uri=uri)
    client.create_experiment("mosd")  # as mosd made it before it set the kind
    MlflowStore(settings).experiment_id()
    assert _experiment_tags(uri).get(KIND_TAG) == TRAINING_KIND
    other = TrackingSettings(uri, (tmp_path / "art").as_uri(), "chosen")
    client.set_experiment_tag(client.create_experiment("chosen"), KIND_TAG, "genai_development")
    MlflowStore(other).experiment_id()
    assert client.get_experiment_by_name("chosen").tags[KIND_TAG] == "genai_development"


# ---------------------------------------------------------------------------------------
# the browser
# ---------------------------------------------------------------------------------------
def _env(outputs: Path) -> dict:
    from test_app import PACKAGE_PARENT

    env = {k: v for k, v in os.environ.items() if not k.startswith("MOSD_") and k != "HYDRA_FULL_ERROR"}
    env["PYTHONPATH"] = os.pathsep.join(p for p in (PACKAGE_PARENT, env.get("PYTHONPATH")) if p)
    env["MOSD_OUTPUTS"] = str(outputs)
    return env


def _serve(store: Path, log: Path) -> tuple[subprocess.Popen, str]:
    """``mlflow server --workers 1`` on a free loopback port, once it answers /health."""
    mlflow_cli = shutil.which("mlflow", path=str(Path(sys.executable).parent)) or shutil.which("mlflow")
    assert mlflow_cli is not None, "the mlflow command is not installed"
    port = free_port()
    server = subprocess.Popen([mlflow_cli, "server", "--workers", "1", "--host", "127.0.0.1", "--port", str(port),
                               "--backend-store-uri", f"sqlite:///{store}"], stdout=log.open("w"),
                              stderr=subprocess.STDOUT, start_new_session=True,
                              env={**os.environ, "MLFLOW_SERVER_ENABLE_JOB_EXECUTION": "false"})  # mlflow-ui.md
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 180
    while True:
        assert server.poll() is None, log.read_text()[-3000:]
        try:
            with urllib.request.urlopen(f"{url}/health", timeout=2):
                return server, url
        except OSError:
            if time.monotonic() > deadline:
                stop_process_group(server)
                raise AssertionError(f"mlflow server did not answer within 180 s:\n{log.read_text()[-3000:]}")
            time.sleep(0.5)


def _browser(profile: Path):
    for path in (CHROMIUM, CHROMEDRIVER):
        assert Path(path).exists(), f"{path} is missing: apt-get install chromium chromium-driver (.ci/run does)"
    from selenium import webdriver
    from selenium.webdriver.chrome.service import Service

    options = webdriver.ChromeOptions()
    options.binary_location = CHROMIUM
    for flag in (*CHROMIUM_FLAGS, f"--user-data-dir={profile}"):
        options.add_argument(flag)
    # the Debian driver by its path: Selenium's own driver manager would try to download one
    return webdriver.Chrome(options=options, service=Service(CHROMEDRIVER))


def _click(driver, find, timeout: float = 30.0) -> None:
    """``find(driver).click()``, found again while the element goes stale.

    The runs grid re-renders its rows when the UI's calls return (slower on a busy machine, e.g. beside
    another pytest-xdist worker): an element found just before is then detached and its click raises
    StaleElementReferenceException without clicking; the same row, found again, takes the click.
    """
    from selenium.common.exceptions import StaleElementReferenceException

    deadline = time.monotonic() + timeout
    while True:
        try:
            find(driver).click()
            return
        except StaleElementReferenceException:
            if time.monotonic() > deadline:
                raise
            time.sleep(0.2)


class Page:
    """A browser tab on the MLflow UI: navigate, wait for text, screenshot."""

    def __init__(self, driver, base: str, shots: Path):
        self.driver, self.base, self.shots = driver, base, shots

    def open(self, fragment: str) -> None:
        self.driver.get(f"{self.base}/#{fragment}")

    def text(self) -> str:
        return self.driver.find_element("tag name", "body").text

    def wait_for(self, *needles: str, timeout: float = 90.0) -> str:
        """The page's text once every needle is in it (the UI renders after its API calls)."""
        deadline = time.monotonic() + timeout
        while True:
            text = self.text()
            if all(n in text for n in needles):
                return text
            if time.monotonic() > deadline:
                self.shot("timeout")
                missing = [n for n in needles if n not in text]
                raise AssertionError(f"{missing} not shown at {self.driver.current_url}; the page says:\n{text[:2000]}")
            time.sleep(0.5)

    def click_text(self, text: str) -> None:
        from selenium.webdriver.common.by import By

        _click(self.driver, lambda d: d.find_element(By.XPATH, f"//*[normalize-space(text())={text!r}]"))

    def shot(self, name: str) -> Path:
        path = self.shots / f"{name}.png"
        self.driver.save_screenshot(str(path))
        return path


@pytest.fixture(scope="module")
def served_sweep(tmp_path_factory):
    """A store with one 4-job sweep made by the command line, served by ``mlflow server``."""
    root = tmp_path_factory.mktemp("ui")
    out = subprocess.run([sys.executable, "-m", "mosd", *SWEEP], cwd=root, env=_env(root / "outputs"),
                         capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-3000:]
    server, url = _serve(root / "outputs" / "mlflow.db", root / "server.log")
    try:
        yield root, url
    finally:
        stop_process_group(server)


@pytest.fixture
def page(served_sweep, tmp_path):
    root, url = served_sweep
    shots = Path(os.environ.get("MOSD_UI_SHOTS") or tmp_path)
    shots.mkdir(parents=True, exist_ok=True)
    driver = _browser(Path(tempfile.mkdtemp(dir=tmp_path, prefix="chromium-")))
    driver.set_page_load_timeout(120)
    try:
        yield Page(driver, url, shots)
    finally:
        driver.quit()


def _runs(uri: str):
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=uri)
    experiment = client.get_experiment_by_name("mosd")
    runs = client.search_runs([experiment.experiment_id], max_results=100)
    parent = next(r for r in runs if r.data.tags.get("mosd.role") == "sweep")
    children = [r for r in runs if r.data.tags.get("mlflow.parentRunId") == parent.info.run_id]
    return client, experiment, parent, children


def _choose(page: Page, label: str, values: list[str]) -> None:
    """Set the compare view's plot selector after ``label`` ("Parameters:"/"Metrics:") to ``values``."""
    from selenium.webdriver.common.by import By
    from selenium.webdriver.common.keys import Keys

    box = page.driver.find_element(By.XPATH, f"//*[normalize-space(text())={label!r}]/following::input[1]")
    for value in values:
        box.click()
        box.send_keys(value)
        # the option named exactly so (typing "far" also offers "best_far")
        option = f"//*[@role='option' or contains(@class,'select-item-option')][@title={value!r} or normalize-space(.)={value!r}]"
        deadline = time.monotonic() + 30
        while not (found := [o for o in page.driver.find_elements(By.XPATH, option) if o.is_displayed()]):
            assert time.monotonic() < deadline, f"{value!r} is not offered under {label!r}"
            time.sleep(0.3)
        found[0].click()
    box.send_keys(Keys.ESCAPE)


def _link_in_virtual_table(page: Page, text: str):
    """The link ``text`` of the compare view's metric table, which renders only the rows in view: scroll to it."""
    from selenium.webdriver.common.by import By

    for _ in range(60):
        found = page.driver.find_elements(By.XPATH, f"//a[normalize-space(text())={text!r}]")
        if found:
            page.driver.execute_script("arguments[0].scrollIntoView({block: 'center'});", found[0])
            return found[0]
        page.driver.execute_script("document.querySelectorAll('.ReactVirtualized__Grid')"
                                   ".forEach(grid => { grid.scrollTop += 60; });")
        time.sleep(0.3)
    raise AssertionError(f"no link {text!r} in the compare view's tables")


@pytest.mark.slow
def test_the_ui_shows_the_sweep_its_children_their_comparison_and_the_hypervolume(page, served_sweep):
    from selenium.webdriver.common.by import By

    _, url = served_sweep
    client, experiment, parent, children = _runs(url)
    assert len(children) == 4
    assert {c.info.status for c in children} == {"FINISHED"}
    assert experiment.tags.get(KIND_TAG) == TRAINING_KIND
    eid, driver = experiment.experiment_id, page.driver

    # the runs at docs/how-to/mlflow-ui.md's address: the training runs, not the GenAI overview
    page.open(f"/experiments/{eid}?workflowType=machine_learning")
    text = page.wait_for(parent.info.run_name, "5 matching runs")
    assert "/runs" in driver.current_url and "Token Usage" not in text
    for close in driver.find_elements(By.CSS_SELECTOR, "button[aria-label='Close']"):  # the assistant's panel
        close.click()
    page.shot("runs")

    # the sweep's parent row opens onto its four children
    names = [c.info.run_name for c in children]
    assert not any(name in page.text() for name in names)  # folded under the parent until opened
    row = f"//div[@role='row' and @row-id='{parent.info.run_id}']"
    expand = f"{row}//button[contains(@data-component-id,'runnamecellrenderer')]"
    _click(driver, lambda d: d.find_element(By.XPATH, expand))
    page.wait_for(*names)
    page.shot("runs-sweep-expanded")

    # select the children, Compare: the swept params (those that differ) and FAR/MDR of each
    for child in children:
        _click(driver, lambda d: d.find_element(By.XPATH, f"//div[@role='row' and @row-id='{child.info.run_id}']"
                                                          f"//input[contains(@class,'ag-checkbox-input')]"))
    _click(driver, lambda d: next(b for b in d.find_elements(By.TAG_NAME, "button") if b.text.strip() == "Compare"))
    swept = sorted(k for k in children[0].data.params
                   if len({c.data.params.get(k) for c in children}) > 1 and not k.startswith(("tracking.", "outputs")))
    assert {"fault.kind", "optimizer._target_"} <= set(swept)
    text = page.wait_for("Comparing 4 Runs", *names, *swept)
    lines = text.splitlines()
    for key in swept:  # the params table: one line per param, a value per run
        line = next(line for line in lines if line.startswith(f"{key} "))
        assert sorted(line.split()[1:]) == sorted(c.data.params[key] for c in children), line
    # the parallel-coordinates plot on the swept choices and the two rates: each axis spans the runs' values
    driver.find_element(By.XPATH, "//button[normalize-space(.)='Clear All']").click()
    _choose(page, "Parameters:", ["fault.kind", "optimizer._target_"])
    _choose(page, "Metrics:", ["far", "mdr"])
    for close in driver.find_elements(By.CSS_SELECTOR, "button[aria-label='Close']"):
        close.click()
    bounds = [f"{f(c.data.metrics[key] for c in children):.5f}" for key in ("far", "mdr") for f in (min, max)]
    text = page.wait_for("fault.kind", "optimizer._target_", *bounds)
    plot = text[text.index("Clear All"):text.index("Run details")]
    assert {"far", "mdr", "offset", "variance"} <= set(plot.split()), plot
    page.shot("compare")

    # the hypervolume per generation, for the four children on one chart (the metric's link)
    _link_in_virtual_table(page, "hypervolume").click()
    n_gen = int(children[0].data.params["optimizer.n_gen"])
    latest = []
    for child in children:
        history = sorted(client.get_metric_history(child.info.run_id, "hypervolume"), key=lambda m: m.step)
        assert [m.step for m in history] == list(range(1, n_gen + 1))
        latest.append(f"{history[-1].value!r} (step={n_gen})")  # the table under the chart: latest value per run
    page.wait_for("Step", *names, *latest)
    assert "/metric" in driver.current_url
    page.shot("hypervolume")


# ---------------------------------------------------------------------------------------
# mosd ui: open the UI, click the experiment, land on the runs table with FAR and MDR
# ---------------------------------------------------------------------------------------
ONE_RUN = ["+fault=offset", "optimizer.pop_size=6", "optimizer.n_gen=2", "budget.n_test=2", "budget.n_train=2",
           "budget.n_calibration=2", "optimizer.n_jobs=1", "progress=false", "scenario.duration=3"]


def _mosd_ui(root: Path, uri: str) -> tuple[subprocess.Popen, dict]:
    """``mosd ui`` on a free port: the process and the addresses it printed, once the server answers."""
    port = free_port()
    log = root / "ui.log"
    ui = subprocess.Popen([sys.executable, "-m", "mosd", "ui", "--port", str(port), "--tracking-uri", uri],
                          cwd=root, env=_env(root / "outputs"), stdout=log.open("w"), stderr=subprocess.STDOUT,
                          start_new_session=True)
    url = f"http://127.0.0.1:{port}"
    deadline = time.monotonic() + 180
    while True:
        assert ui.poll() is None, log.read_text()[-3000:]
        try:
            with urllib.request.urlopen(f"{url}/health", timeout=2):
                break
        except OSError:
            if time.monotonic() > deadline:
                stop_process_group(ui)
                raise AssertionError(f"mosd ui did not serve within 180 s:\n{log.read_text()[-3000:]}")
            time.sleep(0.5)
    printed = {}
    for line in log.read_text().splitlines():
        label, _, address = line.partition("  ")
        if address.strip().startswith("http"):
            printed.setdefault(label.strip(), address.strip())
    return ui, printed


@pytest.mark.slow
def test_mosd_ui_lands_a_click_on_the_experiment_on_the_runs_table_with_far_and_mdr(tmp_path):
    from selenium.webdriver.common.by import By

    out = subprocess.run([sys.executable, "-m", "mosd", *ONE_RUN], cwd=tmp_path, env=_env(tmp_path / "outputs"),
                         capture_output=True, text=True, timeout=900)
    assert out.returncode == 0, out.stderr[-3000:]
    uri = f"sqlite:///{tmp_path / 'outputs' / 'mlflow.db'}"
    from mlflow.tracking import MlflowClient

    client = MlflowClient(tracking_uri=uri)
    experiment = client.get_experiment_by_name("mosd")
    (run,) = client.search_runs([experiment.experiment_id])
    assert run.info.run_name == "offset-ss_dewma-mopso"
    # the run's summary names the runs table: the address mosd ui serves
    summary_ui = next(line for line in out.stdout.splitlines() if line.startswith("ui "))
    assert f"#/experiments/{experiment.experiment_id}/runs?workflowType=machine_learning" in summary_ui
    ui, printed = _mosd_ui(tmp_path, uri)
    driver = _browser(Path(tempfile.mkdtemp(dir=tmp_path, prefix="chromium-")))  # a browser that chose nothing
    driver.set_page_load_timeout(120)
    try:
        page = Page(driver, printed["experiments"].split("/#")[0], Path(os.environ.get("MOSD_UI_SHOTS") or tmp_path))
        driver.get(printed["experiments"])  # the experiment list, as mosd ui printed it
        page.wait_for("mosd", "Experiments")
        link = f"//a[@data-testid='experiment-list-item-link' and normalize-space(.)='mosd']"
        deadline = time.monotonic() + 60
        while not driver.find_elements(By.XPATH, link):
            assert time.monotonic() < deadline, page.text()[:2000]
            time.sleep(0.5)
        driver.find_element(By.XPATH, link).click()  # one click, as a person does
        text = page.wait_for(run.info.run_name, "Metrics", "far", "1 matching run")
        assert f"/experiments/{experiment.experiment_id}/runs" in driver.current_url
        assert "No data available" not in text and "Token Usage" not in text  # not the GenAI overview
        for close in driver.find_elements(By.CSS_SELECTOR, "button[aria-label='Close']"):  # the assistant's panel
            close.click()
        # the grid renders the columns in view: its header row names them all (ag-grid's col-id)
        deadline = time.monotonic() + 30
        while True:
            headers = {h.get_attribute("col-id") for h in driver.find_elements(By.CSS_SELECTOR, ".ag-header-cell")}
            if {"metrics.`far`", "metrics.`mdr`"} <= headers or time.monotonic() > deadline:
                break
            time.sleep(0.5)
        assert {"metrics.`far`", "metrics.`mdr`"} <= headers, headers
        text = page.text()
        # the cells under FAR and MDR hold the run's values
        shown = f"{run.data.metrics['far']:.4g}"[:4], f"{run.data.metrics['mdr']:.4g}"[:4]
        assert all(value in text for value in shown), (shown, text[:2000])
        page.shot("mosd-ui-runs")
        # the printed runs-table address opens the same view
        driver.get(printed["runs table"])
        page.wait_for(run.info.run_name, "Metrics", "far")
        assert "viewStateShareKey=mosd" in driver.current_url
    finally:
        driver.quit()
        stop_process_group(ui)
