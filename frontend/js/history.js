// Undo and redo: each command is already applied when recorded, and knows how to undo and redo itself.
export class History {
  constructor(limit = 1000) {
    this.limit = limit;
    this.done = [];
    this.undone = [];
    this.onchange = null;
  }

  record(command) {
    this.done.push(command);
    if (this.done.length > this.limit) this.done.shift();
    this.undone = [];
    this._changed();
  }

  undo() {
    const command = this.done.pop();
    if (!command) return null;
    command.undo();
    this.undone.push(command);
    this._changed();
    return command;
  }

  redo() {
    const command = this.undone.pop();
    if (!command) return null;
    command.redo();
    this.done.push(command);
    this._changed();
    return command;
  }

  clear() {
    this.done = [];
    this.undone = [];
    this._changed();
  }

  get canUndo() {
    return this.done.length > 0;
  }

  get canRedo() {
    return this.undone.length > 0;
  }

  _changed() {
    if (this.onchange) this.onchange(this);
  }
}
