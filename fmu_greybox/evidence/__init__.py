"""evidence: what every page shows: figures, frequency responses, the HTML kit, the glossary."""
