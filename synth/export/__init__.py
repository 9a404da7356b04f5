"""The dataset export: config, random scenes, one sample, resumable shards, real captures in the same schema, systems drawn from a posterior."""
