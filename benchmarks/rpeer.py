"""R SuppDists' quantile Johnson fit, `JohnsonFit(x, moment="quant")`, as a peer.

Every histogram goes to one Rscript run: R rebuilds the values (each level repeated by its
count), fits, and returns the parameters and the model's probability of each level (its mass
over [k - 1/2, k + 1/2], tails folded into the end levels) from SuppDists' own `pJohnson`.
A case where R raises, or returns non-finite or out-of-range parameters, is a failure.
(`pJohnson` itself raises for points outside an SB's support; there the cdf is 0 or 1.)
"""
from __future__ import annotations

import shutil
import subprocess
import tempfile
from dataclasses import dataclass
from pathlib import Path

import numpy as np

_SCRIPT = r"""
suppressPackageStartupMessages(library(SuppDists))
args <- commandArgs(trailingOnly = TRUE)
h <- as.matrix(read.table(args[1], header = FALSE))
levels <- ncol(h)
jitter <- args[3] == "jitter"
edges <- seq(0.5, levels - 1.5, by = 1)
out <- file(args[2], "w")
for (i in seq_len(nrow(h))) {
  x <- rep(0:(levels - 1), h[i, ])
  if (jitter) { set.seed(i); x <- x + runif(length(x), -0.5, 0.5) }
  line <- tryCatch({
    t0 <- proc.time()[["elapsed"]]
    p <- JohnsonFit(x, moment = "quant")
    seconds <- proc.time()[["elapsed"]] - t0
    cdf <- numeric(length(edges))
    if (p$type == "SB") {
      # pJohnson raises outside an SB's support; there the cdf is 0 or 1
      inside <- edges > p$xi & edges < p$xi + p$lambda
      cdf[edges >= p$xi + p$lambda] <- 1
      if (any(inside)) cdf[inside] <- pJohnson(edges[inside], p)
    } else cdf <- pJohnson(edges, p)
    probs <- diff(c(0, cdf, 1))
    paste(c(p$type, format(c(seconds, p$gamma, p$delta, p$xi, p$lambda, probs), digits = 17)), collapse = " ")
  }, error = function(e) paste("ERROR", gsub("[\r\n ]+", "_", conditionMessage(e))))
  writeLines(line, out)
}
close(out)
"""


@dataclass(frozen=True, slots=True)
class RFit:
    family: str | None  # SN, SL, SU, SB; None when R failed
    params: tuple[float, float, float, float] | None  # gamma, delta, xi, lambda
    probs: np.ndarray | None  # level probabilities
    error: str = ""
    seconds: float = 0.0  # JohnsonFit's own time in R (proc.time, 1 ms resolution)


def available() -> bool:
    if shutil.which("Rscript") is None:
        return False
    run = subprocess.run(["Rscript", "-e", "library(SuppDists)"], capture_output=True, timeout=60)
    return run.returncode == 0


def fit_all(histograms: list[np.ndarray], jitter: bool = True, timeout: float = 600.0) -> list[RFit]:
    """R's fit of each histogram (equal lengths), in one Rscript process. With `jitter` R sees
    the dequantized values (each level's pixels spread uniformly over it, seeded per case), as
    our fit reads the levels; on the integer values themselves its SB solve fails on most
    photographs ("Sb values out of range") because tied quantiles make the gaps degenerate."""
    with tempfile.TemporaryDirectory() as tmp:
        src, dst, script = Path(tmp) / "h.txt", Path(tmp) / "out.txt", Path(tmp) / "fit.R"
        np.savetxt(src, np.stack(histograms).astype(np.int64), fmt="%d")
        script.write_text(_SCRIPT, encoding="utf-8")
        subprocess.run(["Rscript", str(script), str(src), str(dst), "jitter" if jitter else "raw"], check=True,
                       capture_output=True, timeout=timeout)
        return [_parse(line) for line in dst.read_text(encoding="utf-8").splitlines()]


def _parse(line: str) -> RFit:
    fields = line.split()
    if fields[0] == "ERROR":
        return RFit(None, None, None, " ".join(fields[1:]).replace("_", " ") or "error")
    family = fields[0]
    seconds = float(fields[1])
    values = np.array([float(v) for v in fields[2:]])
    gamma, delta, xi, lam = values[:4]
    probs = values[4:]
    params = (float(gamma), float(delta), float(xi), float(lam))
    if not np.isfinite(values[:4]).all() or delta <= 0 or (family == "SB" and lam <= 0) or lam == 0:
        return RFit(family, params, None, f"out-of-range parameters {params}", seconds)
    if not np.isfinite(probs).all():
        return RFit(family, params, None, "non-finite probabilities", seconds)
    if abs(probs.sum() - 1.0) > 1e-6 or probs.min() < -1e-12:
        return RFit(family, params, None, "probabilities do not sum to 1", seconds)
    return RFit(family, params, np.clip(probs, 0.0, None), "", seconds)
