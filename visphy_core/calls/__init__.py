"""Calls to providers: prompts, generation with retries and repair, usage and cost, API keys and
secret redaction, judging, reference captions.
(See docs/architecture.md.)"""
