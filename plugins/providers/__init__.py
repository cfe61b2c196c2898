"""Provider clients over the official SDKs, shared by model adapters and judges."""
